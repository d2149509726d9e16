"""The layout holds: imports run one way between the wings, matplotlib stays in reports/.

Wings, from the top: cli → reports → study, measurement → allocation, sobol →
montecarlo, worstcase, stackup → model → kinematics → foundations (the
top-level modules). A module may import its own wing and any wing below;
wings on one floor (the methods side by side) never import each other.
"""

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / "prp3mc"
LEVEL = {"cli": 7, "reports": 6, "study": 5, "measurement": 5, "allocation": 4, "sobol": 4,
         "montecarlo": 3, "worstcase": 3, "stackup": 3, "model": 2, "kinematics": 1}
TOP = {"__init__", "__main__", "testing"}          # top-level modules allowed to import any wing


def wing(parts: tuple) -> str:
    """The wing of a module given its dotted path below prp3mc ('' for a foundation)."""
    return parts[0] if parts and parts[0] in LEVEL else ""


def imports(path: pathlib.Path) -> list[tuple[str, ...]]:
    """prp3mc modules imported by ``path``, as dotted paths below prp3mc."""
    rel = path.relative_to(PACKAGE).with_suffix("").parts
    package = rel[:-1] if rel[-1] != "__init__" else rel[:-1]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)] if node.level > 1 else package
                target = base + tuple(node.module.split(".")) if node.module else base
            elif node.module and node.module.split(".")[0] == "prp3mc":
                target = tuple(node.module.split(".")[1:])
            else:
                continue
            out.append(target)
        elif isinstance(node, ast.Import):
            out += [tuple(a.name.split(".")[1:]) for a in node.names if a.name.split(".")[0] == "prp3mc"]
    return out


MODULES = sorted(p for p in PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_run_one_way(path):
    rel = path.relative_to(PACKAGE).with_suffix("").parts
    if len(rel) == 1 and rel[0] in TOP:
        return
    own = wing(rel)
    for target in imports(path):
        other = wing(target)
        if other == own or other == "":
            continue
        assert own, f"foundation {path.name} imports the {other} wing"
        assert LEVEL[other] != LEVEL[own], f"{path} imports {'.'.join(target)} (a wing on its own floor)"
        assert LEVEL[other] < LEVEL[own], f"{path} imports {'.'.join(target)} (upwards)"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_only_reports_import_matplotlib_and_nobody_switches_backend(path):
    text = path.read_text(encoding="utf-8")
    assert "matplotlib.use(" not in text
    rel = path.relative_to(PACKAGE).parts
    if rel[0] != "reports":
        tree = ast.parse(text)
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        assert not any(n.split(".")[0] in ("matplotlib", "seaborn") for n in names), path
