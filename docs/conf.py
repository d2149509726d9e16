"""Sphinx configuration of the prp3mc documentation.

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html`` (the README's test command does).
Three things are made at each build, from the code, into folders git ignores: the notebooks copied
from ../notebooks, the command-line help of every command, and the API reference's module pages
(autosummary, recursive: a module added to the package appears without an edit here).
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))          # the checkout's prp3mc, installed or not

import prp3mc  # noqa: E402
from prp3mc.cli import build_parser  # noqa: E402

project = "prp3mc"
author = "prp3mc developers"
copyright = "prp3mc developers"
release = version = prp3mc.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_nb",
]
exclude_patterns = ["_build", "**.ipynb_checkpoints", "api/_everyday.rst"]    # the last: included, no page
templates_path = ["_templates"]

# API reference: autosummary walks the package; numpydoc renders the docstrings' sections
autosummary_generate = True
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_typehints = "none"             # the numpydoc sections carry types, shapes and units
autodoc_member_order = "bysource"
numpydoc_show_class_members = False    # autodoc lists the members on the class's own page
numpydoc_class_members_toctree = False

# Markdown pages (MyST) and notebooks (myst-nb), rendered with their stored outputs: the tests execute them
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = "off"

html_theme = "pydata_sphinx_theme"
html_title = f"prp3mc {release}"
html_theme_options = {"show_toc_level": 2, "navigation_with_keys": False, "secondary_sidebar_items": ["page-toc"]}
html_static_path = ["_static"]
html_css_files = ["wide.css"]


def _copy_notebooks() -> None:
    """The notebooks as the tests run them (../notebooks), under docs/notebooks/ for the site."""
    target = DOCS / "notebooks"
    shutil.rmtree(target, ignore_errors=True)
    target.mkdir()
    for notebook in sorted((ROOT / "notebooks").glob("*.ipynb")):
        shutil.copy2(notebook, target / notebook.name)


def _write_cli_help() -> None:
    """``prp3mc COMMAND --help`` of every registered command: the page api/commands.md."""
    os.environ["COLUMNS"] = "86"       # argparse wraps at the terminal's width: fit the page
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    parts = ["# Command reference", "", "Every command's `--help`, as this version prints it (the",
             "[command-line guide](../guide/cli.md) shows them at work).", "",
             "```text", parser.format_help().rstrip(), "```"]
    for name, sub in sorted(commands.items()):
        parts += ["", f"## `prp3mc {name}`", "", "```text", sub.format_help().rstrip(), "```"]
    _write("commands.md", "\n".join(parts) + "\n")


def _write_everyday_api() -> None:
    """The names ``import prp3mc`` offers, each linked to the page of the module that defines it."""
    rows: dict[str, list[str]] = {}
    for name in prp3mc.__all__:
        if name.startswith("__"):
            continue
        obj = getattr(prp3mc, name)                  # sobol_ranking is prp3mc.sobol.ranking.ranking
        rows.setdefault(obj.__module__.split(".")[1], []).append(f"   ~{obj.__module__[len('prp3mc.'):]}.{obj.__qualname__}")
    parts = []
    for wing, names in rows.items():
        parts += [f".. rubric:: {wing}", "", ".. autosummary::", "", *names, ""]
    _write("_everyday.rst", "\n".join(parts))


def _write(name: str, text: str) -> None:
    """Write api/NAME unless it holds ``text`` already (then its readers need no rebuild)."""
    path = DOCS / "api" / name
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


_copy_notebooks()
_write_cli_help()
_write_everyday_api()
