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


#: The discrepancy workflow's steps inside measurement/, one package per step, from the bottom.
FIT_STEP = {"forward": 1, "estimation": 2, "naming": 3, "verdict": 3, "discrepancy": 4}
FIT_MODULES = [p for p in MODULES if p.relative_to(PACKAGE).parts[:2] in {("measurement", k) for k in FIT_STEP}]


@pytest.mark.parametrize("path", FIT_MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_the_workflow_steps_import_downwards(path):
    """forward → estimation → naming, verdict (side by side) → discrepancy: a step imports only the steps below."""
    own = FIT_STEP[path.relative_to(PACKAGE).parts[1]]
    for target in imports(path):
        if target[:1] == ("measurement",) and len(target) > 1 and target[1] in FIT_STEP:
            other = FIT_STEP[target[1]]
            assert other < own or target[1] == path.relative_to(PACKAGE).parts[1], \
                f"{path.relative_to(PACKAGE)} imports {'.'.join(target)}"


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


def _owned(tree: ast.AST) -> set[str]:
    """The underscore names a module gives its own objects: functions, classes, class fields, ``self._x``."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    targets = item.targets if isinstance(item, ast.Assign) else [getattr(item, "target", None)]
                    out |= {t.id for t in targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            out.add(node.attr)
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "__setattr__" and len(node.args) > 1:
            if isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str):
                out.add(node.args[1].value)
    return {name for name in out if name.startswith("_") and not name.startswith("__")}


def private_reads(tree: ast.AST) -> list[tuple[str, str]]:
    """``(object, attribute)`` of every read of an underscore attribute of an object other than self or cls."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            if not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
                out.append((ast.unparse(node.value), node.attr))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr")
              and len(node.args) > 1 and isinstance(node.args[1], ast.Constant)
              and str(node.args[1].value).startswith("_") and not str(node.args[1].value).startswith("__")):
            out.append((ast.unparse(node.args[0]), node.args[1].value))
    return out


TREES = {p: ast.parse(p.read_text(encoding="utf-8")) for p in MODULES}
OWNERS: dict[str, set] = {}
for _path, _tree in TREES.items():
    for _name in _owned(_tree):
        OWNERS.setdefault(_name, set()).add(_path)


def foreign_private_reads(path: pathlib.Path, tree: ast.AST) -> list[str]:
    """Reads in ``path`` of an underscore attribute that another prp3mc module (and not this one) defines."""
    return [f"{obj}.{attr}" for obj, attr in private_reads(tree)
            if attr in OWNERS and path not in OWNERS[attr]]


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_module_reads_another_modules_private_attributes(path):
    """A model's private structure (e.g. what ``LinearModel`` keeps of its terms) stays in its module:
    other modules read the public description (``LinearModel.term_laws``)."""
    assert not foreign_private_reads(path, TREES[path]), path


def test_the_private_read_check_sees_one():
    """The check above flags a read like the former ``model._plan`` outside its module, and not ``self._x``."""
    owner = PACKAGE / "model" / "linear.py"
    OWNERS.setdefault("_plan_probe", set()).add(owner)
    try:
        reader = ast.parse("def f(model):\n    return model._plan_probe, getattr(model, '_plan_probe')\n")
        assert foreign_private_reads(PACKAGE / "sobol" / "ranking.py", reader) == ["model._plan_probe"] * 2
        assert foreign_private_reads(owner, reader) == []
        assert foreign_private_reads(owner, ast.parse("def f(self):\n    return self._plan_probe\n")) == []
    finally:
        OWNERS.pop("_plan_probe")


EFFECT_KINDS = {"offset", "scale", "backlash", "thermal", "cyclic", "spread"}


def kind_string_compares(tree: ast.AST) -> list[str]:
    """Comparisons of an effect's ``kind`` (or a name called ``kind``) with an effect kind's name as a string."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            kind = any(isinstance(s, ast.Attribute) and s.attr == "kind" or isinstance(s, ast.Name) and s.id == "kind"
                       for s in sides)
            consts = {c.value for s in sides for c in ([s] if isinstance(s, ast.Constant) else
                      getattr(s, "elts", [])) if isinstance(c, ast.Constant)}
            if kind and consts & EFFECT_KINDS:
                out.append(ast.unparse(node))
    return out


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_effect_kinds_are_dispatched_through_the_registry(path):
    """Effect kinds are the members of ``EffectKind`` and their attributes, not strings compared in every module."""
    found = kind_string_compares(TREES[path])
    assert not found, f"{path.relative_to(PACKAGE)}: {found}"
