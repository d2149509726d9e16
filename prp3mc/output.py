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

__all__ = ["OutputExistsError", "FigureFormatError", "output_folder", "write_json", "write_text", "save_figure",
           "png_data_uri", "figure_formats", "FIGURE_FORMATS"]


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


class FigureFormatError(Prp3mcError, ValueError):
    """A figure format that reports cannot write."""


#: Figure formats a report can write.
FIGURE_FORMATS = ("png", "svg")


def figure_formats(spec) -> tuple[str, ...]:
    """Figure formats from a comma-separated string such as ``"png,svg"`` or a sequence."""
    text = spec if isinstance(spec, str) else ",".join(spec)
    formats = tuple(dict.fromkeys(f.strip().lower() for f in text.split(",") if f.strip()))
    bad = [f for f in formats if f not in FIGURE_FORMATS]
    if bad or not formats:
        raise FigureFormatError(f"figure formats must be among {', '.join(FIGURE_FORMATS)}, got {text!r}")
    return formats


def save_figure(fig, folder: str | os.PathLike, name: str, formats=("png",), dpi: int = 150) -> bytes:
    """Save a figure as ``folder/name.<format>`` for every format; return its PNG bytes.

    Each format is rendered once, without a tight bounding box (the figures
    use a constrained layout); the PNG is rendered even if not written, so a
    report embeds the very same bytes (:func:`png_data_uri`).
    """
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=dpi)
    for fmt in formats:
        path = Path(folder) / f"{name}.{fmt}"
        if fmt == "png":
            path.write_bytes(png.getvalue())
        else:
            fig.savefig(path, format=fmt, dpi=dpi)
    return png.getvalue()


def png_data_uri(png: bytes) -> str:
    """PNG bytes as a base64 ``data:`` URI, to embed in a self-contained HTML file."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")
