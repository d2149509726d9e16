"""Writing results safely: output folders, atomic files, figures.

Nothing the user had is lost and no two runs mix their results:

- A run *claims* its output folder before it computes (:func:`claim_output`):
  an advisory lock on the sibling file ``.NAME.lock`` (``flock``, released by
  the kernel when the process dies, so a killed run leaves no live lock). Of
  two runs on the same folder one holds the claim and the other stops at once
  with one line naming the holder's PID. An existing folder is refused
  unless ``force``.
- The run writes into a hidden sibling ``.NAME.tmp-PID-XXXX`` and moves it
  into place at the end (:func:`output_folder`) while it still holds the
  claim: with ``renameat2`` (Linux) the move never replaces a folder that
  appeared meanwhile, and ``force`` swaps old and new atomically.
- Leftovers of a killed run (``.NAME.tmp-…`` and ``.NAME.old-…`` siblings, and
  the unlocked lock file) are removed by the next run that claims the folder;
  an ``.old`` folder whose replacement never arrived is put back.

Single files are written through a temporary file and an atomic rename.
"""

from __future__ import annotations

import base64
import ctypes
import errno
import fcntl
import io
import json
import math
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator

from .errors import (FigureFormatError, MissingDependencyError, OutputBusyError, OutputError, OutputExistsError,
                     Prp3mcError)

__all__ = ["claim_output", "output_folder", "check_output", "dumps_json", "write_json", "write_text", "write_csv",
           "check_json", "save_figure", "png_data_uri", "figure_formats", "FIGURE_FORMATS", "TABLE_FORMATS",
           "table_formats", "write_workbook"]


#: Folders claimed by this process (resolved path -> force), so that nested
#: writers (a report inside a command that claimed its --out) share the claim.
_HELD: dict[Path, bool] = {}

_RENAME_NOREPLACE, _RENAME_EXCHANGE, _AT_FDCWD = 1, 2, -100
_LIBC = ctypes.CDLL(None, use_errno=True)
_renameat2 = getattr(_LIBC, "renameat2", None)


def _rename(src: Path, dst: Path, flags: int) -> bool:
    """``renameat2(src, dst, flags)``; False where the system lacks it (then the caller falls back)."""
    if _renameat2 is None:
        return False
    if _renameat2(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flags) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):  # kernel or file system without it
        return False
    raise OSError(err, os.strerror(err), str(dst))


#: What every folder prp3mc writes holds at its top: ``force`` replaces only such a folder, or an empty one.
OUTPUT_MARKS = ("report.html", "summary.json", "discrepancy.json")


def check_output(path: str | os.PathLike, force: bool, inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Refuse an existing output folder unless ``force``; return it as a Path.

    Even with ``force``, a folder is replaced only if it is empty or an
    earlier output (:data:`OUTPUT_MARKS`), and neither the working folder nor
    one holding it nor one holding any of ``inputs`` (the run's own files):
    nothing the user had is lost to a mistyped ``--out``.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputExistsError(f"{path} exists and is not a folder")
    if path.exists() and not force:
        raise OutputExistsError(f"{path} exists: choose another --out or pass --force to replace it")
    if path.exists():
        real = path.resolve()
        if real == Path.cwd().resolve() or real in Path.cwd().resolve().parents:
            raise OutputExistsError(f"{path} is the working folder or holds it: --force never replaces it; "
                                    "choose a new --out")
        held = next((f for f in inputs if real in Path(f).resolve().parents), None)
        if held is not None:
            raise OutputExistsError(f"{path} holds the input {held}: --force would delete it; choose another --out")
        if any(path.iterdir()) and not any((path / mark).exists() for mark in OUTPUT_MARKS):
            raise OutputExistsError(f"{path} is not an earlier prp3mc output (no {' or '.join(OUTPUT_MARKS)}): "
                                    "--force replaces only those; choose another --out")
    return path


def _leftovers(path: Path) -> re.Pattern:
    """Names of the temporary siblings a run on ``path`` makes (and older releases made)."""
    name = re.escape(path.name)
    return re.compile(rf"^\.{name}\.(?:(?P<tmp>tmp-\d+-[a-z0-9_]+|[a-z0-9_]{{8}})|(?P<old>old-\d+-[a-z0-9_]+|old\d+))$")


def _clean_leftovers(path: Path) -> None:
    """Remove what killed runs left beside ``path``; restore an ``.old`` folder if ``path`` is gone.

    Called only while holding the claim, so no live run owns any of them.
    """
    pattern = _leftovers(path)
    for entry in sorted(path.parent.iterdir()):
        match = pattern.match(entry.name)
        if not match or not entry.is_dir() or entry.is_symlink():
            continue
        if match["old"] and not path.exists():
            os.rename(entry, path)  # killed between moving the old folder out and the new one in
        else:
            shutil.rmtree(entry, ignore_errors=True)


def _lock(path: Path) -> int:
    """Take the advisory lock of ``path`` (``.NAME.lock``); return its descriptor."""
    lock = path.with_name(f".{path.name}.lock")
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "pid unknown"
            os.close(fd)
            raise OutputBusyError(f"{path} is being written by another prp3mc run ({owner}): "
                                  "wait for it to finish or choose another --out") from None
        try:  # the previous holder may have removed the file between our open and our lock
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()}\n".encode("ascii"), 0)
    return fd


def _output_path(path: str | os.PathLike) -> Path:
    """The absolute output folder ``path`` names: a symbolic link to a folder stands for that folder.

    Raises
    ------
    OutputError
        The name is empty or the root folder, or a symbolic link leads nowhere.
    """
    if not str(path).strip():
        raise OutputError("the output folder is empty: name a folder with --out")
    absolute = Path(os.path.abspath(path))
    if not absolute.name:
        raise OutputError(f"--out {os.fsdecode(path)!r} is the root folder: name a new folder under it")
    if absolute.is_symlink():
        if not absolute.exists():
            raise OutputError(f"--out {absolute} is a dangling symbolic link (to {os.readlink(absolute)}): "
                              "remove it or choose another --out")
        return _output_path(absolute.resolve())   # written where the link leads, which keeps leading there
    return absolute


def _umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextmanager
def claim_output(path: str | os.PathLike, force: bool = False,
                 inputs: Iterable[str | os.PathLike] = ()) -> Iterator[Path]:
    """Hold the output folder ``path`` for this run; refuse it if it exists (unless ``force``; see
    :func:`check_output` for what ``force`` never replaces, ``inputs`` among it).

    Commands enter this before they compute, so a second run on the same
    folder, or one on an existing folder, stops before any work. Re-entrant
    within a process: :func:`output_folder` inside the block shares the claim.

    Raises
    ------
    OutputBusyError
        Another live run holds the folder.
    OutputExistsError
        The folder exists and ``force`` is false, or it is not a folder.
    OutputError
        The parent folder cannot be created or written.
    """
    path = _output_path(path)
    if path in _HELD:
        check_output(path, force or _HELD[path])
        yield path
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = _lock(path)
    except OSError as exc:
        if isinstance(exc, Prp3mcError):
            raise
        raise OutputError(f"cannot claim {path}: {exc.strerror or exc}") from None
    _HELD[path] = force
    try:
        _clean_leftovers(path)
        check_output(path, force, inputs)
        yield path
    finally:
        del _HELD[path]
        path.with_name(f".{path.name}.lock").unlink(missing_ok=True)
        os.close(fd)


#: Set once a run starts moving its finished folder into place: from then on the run is complete, and a
#: signal handler (the command line's) lets it finish rather than interrupt it (exit 0, the folder whole).
COMMITTED = {"value": False}


def _install(tmp: Path, path: Path, force: bool) -> None:
    """Move the finished folder ``tmp`` to ``path``; replace an existing one only with ``force``."""
    COMMITTED["value"] = True
    try:
        _move_into_place(tmp, path, force)
    except BaseException:
        COMMITTED["value"] = False
        raise


def _move_into_place(tmp: Path, path: Path, force: bool) -> None:
    if force and path.exists():
        if _rename(tmp, path, _RENAME_EXCHANGE):
            shutil.rmtree(tmp, ignore_errors=True)  # tmp now holds the old folder
            return
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-{os.getpid()}-", dir=path.parent))
        os.replace(path, old)  # an empty folder is replaced by a rename
        os.replace(tmp, path)
        shutil.rmtree(old, ignore_errors=True)
        return
    try:
        if not _rename(tmp, path, _RENAME_NOREPLACE):
            if path.exists():
                raise FileExistsError(errno.EEXIST, "exists", str(path))
            os.rename(tmp, path)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if exc.errno in (errno.EEXIST, errno.ENOTEMPTY):
            raise OutputExistsError(f"{path} appeared while this run was writing it and was left as it is: "
                                    "choose another --out or pass --force") from None
        raise


@contextmanager
def output_folder(path: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield a temporary folder that becomes ``path`` when the block succeeds.

    The folder is claimed for the whole block (see :func:`claim_output`). On
    an exception the temporary folder is removed and ``path`` is untouched.
    """
    with claim_output(path, force) as path:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-{os.getpid()}-", dir=path.parent))
        try:
            os.chmod(tmp, 0o777 & ~_umask())   # mkdtemp makes it 0700: the folder is the user's, as mkdir makes it
            yield tmp
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        _install(tmp, path, force or _HELD[path])


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write text through a temporary file and an atomic rename."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def write_csv(frame, path: str | os.PathLike) -> None:
    """``frame.to_csv(path, index=False)``: the same bytes, a frame of float columns about twice as fast.

    pandas writes each float as its shortest repr, which Python's ``repr``
    gives too: a frame whose columns are all float64 without NaN (which
    pandas writes as nothing) and whose column names need no quotes is
    written row by row from those reprs (the large grids of a report);
    any other frame by pandas.
    """
    import numpy as np
    floats = all(dtype == np.float64 for dtype in frame.dtypes)
    plain = all(isinstance(c, str) and not any(ch in c for ch in ',"\r\n') for c in frame.columns)
    if not (floats and plain) or frame.isna().to_numpy().any():
        frame.to_csv(path, index=False)
        return
    rows = zip(*(frame[c].to_numpy().tolist() for c in frame.columns))
    lines = [",".join(frame.columns), *(",".join(map(repr, row)) for row in rows)]
    Path(path).write_text(os.linesep.join(lines) + os.linesep, encoding="utf-8")


def check_json(obj: Any, where: str = "") -> Any:
    """Return ``obj`` unchanged if it holds no NaN or infinity; else raise naming the first one.

    Raises
    ------
    Prp3mcError
        One line with the key path of the non-finite value (JSON has no NaN).
    """
    if isinstance(obj, float) and not math.isfinite(obj):
        raise Prp3mcError(f"the result is not finite at {where or 'top level'} ({obj}): "
                          "the inputs are out of the model's range")
    if isinstance(obj, dict):
        for key, value in obj.items():
            check_json(value, f"{where}.{key}" if where else str(key))
    elif isinstance(obj, (list, tuple)):
        for k, value in enumerate(obj):
            check_json(value, f"{where}[{k}]")
    return obj


def dumps_json(obj: Any) -> str:
    """JSON text of ``obj``; a NaN or infinity is refused with one line (see :func:`check_json`)."""
    try:
        return json.dumps(obj, indent=2, allow_nan=False)
    except ValueError:
        check_json(obj)
        raise


def write_json(path: str | os.PathLike, obj) -> None:
    """Write JSON (no NaN allowed) atomically."""
    write_text(path, dumps_json(obj) + "\n")


#: Figure formats a report can write.
FIGURE_FORMATS = ("png", "svg")
#: Table formats a report can write besides its CSV files (``xlsx`` needs openpyxl: ``pip install 'prp3mc[xlsx]'``).
TABLE_FORMATS = ("xlsx",)


def _formats(spec) -> tuple[str, ...]:
    """The formats of a comma-separated string such as ``"png,svg,xlsx"`` or a sequence, checked."""
    text = spec if isinstance(spec, str) else ",".join(spec)
    formats = tuple(dict.fromkeys(f.strip().lower() for f in text.split(",") if f.strip()))
    bad = [f for f in formats if f not in FIGURE_FORMATS + TABLE_FORMATS]
    if bad or not formats:
        raise FigureFormatError(f"formats must be among {', '.join(FIGURE_FORMATS + TABLE_FORMATS)}, got {text!r}")
    return formats


def figure_formats(spec) -> tuple[str, ...]:
    """Figure formats of ``spec`` (:func:`_formats`): those it names, ``("png",)`` if it names none."""
    return tuple(f for f in _formats(spec) if f in FIGURE_FORMATS) or ("png",)


def table_formats(spec) -> tuple[str, ...]:
    """Table formats of ``spec``: ``csv`` always, then ``xlsx`` if named (refused with the pip line without openpyxl)."""
    extra = tuple(f for f in _formats(spec) if f in TABLE_FORMATS)
    if "xlsx" in extra:
        import importlib.util
        if importlib.util.find_spec("openpyxl") is None:
            raise MissingDependencyError("openpyxl", "pip install 'prp3mc[xlsx]'", "xlsx tables")
    return ("csv", *extra)


#: Units of column-name suffixes, shown in a workbook's headers.
_SUFFIX_UNITS = {"_mm": "mm", "_um": "µm", "_deg": "deg", "_arcsec": "arcsec", "_pct": "%", "_s": "s",
                 "_C": "°C", "_ppm": "ppm"}


def _header(name: str) -> str:
    """A column name with its unit in brackets, read off its suffix (``position_um`` -> ``position [µm]``)."""
    for suffix, unit in _SUFFIX_UNITS.items():
        if name.endswith(suffix) and len(name) > len(suffix):
            return f"{name[:-len(suffix)]} [{unit}]"
    return name


def write_workbook(tables: dict, path: str | os.PathLike) -> None:
    """Write tables into one Excel workbook, one sheet per table, units in the headers.

    A sheet is named after its table (cut to Excel's 31 characters, made
    unique); a header shows the unit its column name carries
    (``x_mm`` -> ``x [mm]``); a table with a ``unit`` column keeps it (its
    rows differ in unit). Written through a temporary file and a rename.

    Raises
    ------
    FigureFormatError
        openpyxl is not installed (with the pip line).
    """
    try:
        import openpyxl
    except ImportError:
        raise FigureFormatError("xlsx tables need openpyxl: pip install 'prp3mc[xlsx]' (or pip install openpyxl)") from None
    import pandas as pd
    book = openpyxl.Workbook(write_only=True)
    used: set[str] = set()
    for name, frame in tables.items():
        title, k = name[:31], 1
        while title in used:
            k += 1
            title = f"{name[:31 - len(str(k)) - 1]}~{k}"
        used.add(title)
        sheet = book.create_sheet(title)
        sheet.append([_header(str(c)) for c in frame.columns])
        for row in frame.itertuples(index=False):      # numpy scalars as Python ones, NaN and NA as empty cells
            sheet.append([None if pd.isna(v) else v.item() if hasattr(v, "item") else v for v in row])
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    book.save(tmp)
    os.replace(tmp, path)


def save_figure(fig, folder: str | os.PathLike, name: str, formats=("png",), dpi: int = 150) -> bytes:
    """Save a figure as ``folder/name.<format>`` for every format; return its PNG bytes.

    Each format is rendered once, without a tight bounding box; the PNG is
    rendered even if not written, so a report embeds the very same bytes
    (:func:`png_data_uri`). A figure with a layout engine is laid out by the
    PNG's drawing, and the other formats keep that layout (its engine is
    switched off after it): they skip the layout, with the same result.
    """
    png = _png(fig, dpi)
    fig.set_layout_engine("none")      # laid out: the other formats draw it where the PNG did
    for fmt in formats:
        path = Path(folder) / f"{name}.{fmt}"
        if fmt == "png":
            path.write_bytes(png)
        else:
            fig.savefig(path, format=fmt, dpi=dpi)
    return png


def _png(fig, dpi: float) -> bytes:
    """``fig`` drawn once on its Agg canvas at ``dpi``, as PNG bytes: RGB when every pixel is opaque.

    An opaque figure (the reports' white ones) loses nothing without its
    alpha channel, and a quarter less to compress halves the encoding time
    of a large figure (it was a fifth of a report figure's cost).
    """
    import numpy as np
    from PIL import Image
    fig.set_dpi(dpi)
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())
    buf = io.BytesIO()
    Image.fromarray(rgba[..., :3] if (rgba[..., 3] == 255).all() else rgba).save(buf, format="png")
    return buf.getvalue()


def png_data_uri(png: bytes) -> str:
    """PNG bytes as a base64 ``data:`` URI, to embed in a self-contained HTML file."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")
