"""Writing results safely: output folders, atomic files, figures.

Nothing the user had is lost: a run writes into a temporary sibling folder
and renames it into place at the end, an existing folder is replaced only
with ``force=True``, and single files are written through a temporary file
and an atomic rename.
"""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from .errors import Prp3mcError

__all__ = ["OutputExistsError", "output_folder", "write_json", "write_text", "save_figure", "figure_data_uri"]


class OutputExistsError(Prp3mcError, FileExistsError):
    """The output folder exists and ``force`` was not given."""


def check_output(path: str | os.PathLike, force: bool) -> Path:
    """Refuse an existing output folder unless ``force``; return it as a Path."""
    path = Path(path)
    if path.exists() and not force:
        raise OutputExistsError(f"{path} exists: choose another --out or pass --force to replace it")
    if path.exists() and not path.is_dir():
        raise OutputExistsError(f"{path} exists and is not a folder")
    return path


@contextmanager
def output_folder(path: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield a temporary folder that replaces ``path`` when the block succeeds.

    On an exception the temporary folder is removed and ``path`` is untouched.
    """
    path = check_output(path, force)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if path.exists():
        old = path.with_name(f".{path.name}.old{os.getpid()}")
        os.replace(path, old)
    os.replace(tmp, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write text through a temporary file and an atomic rename."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def write_json(path: str | os.PathLike, obj) -> None:
    """Write JSON (no NaN allowed) atomically."""
    write_text(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def save_figure(fig, folder: str | os.PathLike, name: str, formats=("png", "svg"), dpi: int = 150) -> list[Path]:
    """Save a matplotlib figure as ``folder/name.png`` and ``.svg``; return the paths."""
    paths = []
    for fmt in formats:
        p = Path(folder) / f"{name}.{fmt}"
        fig.savefig(p, format=fmt, dpi=dpi, bbox_inches="tight")
        paths.append(p)
    return paths


def figure_data_uri(fig, dpi: int = 110) -> str:
    """The figure as a base64 PNG ``data:`` URI, to embed in a self-contained HTML file."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
