"""What a result was computed from: input files with their hashes, and package versions.

Every JSON output (``--json``, ``summary.json``, ``discrepancy.json``) carries
``"inputs"`` and ``"versions"`` built here, so that an output describes itself:
which geometry and budget (preset name, or file path and sha256), which poses,
seed and sample counts, and which versions of prp3mc and its numerical stack.
"""

from __future__ import annotations

import hashlib
import os
import platform
from importlib import metadata
from pathlib import Path

from ._version import __version__

__all__ = ["versions", "file_record", "spec_record", "sha256_file"]

#: Every package whose version can change a number or a picture: the numerical stack, numba (the compiled
#: kernels' floating-point contractions) and matplotlib (the figures).
_PACKAGES = {"numpy": "numpy", "scipy": "scipy", "pandas": "pandas", "SALib": "SALib", "numba": "numba",
             "matplotlib": "matplotlib"}


def versions() -> dict[str, str]:
    """Versions of prp3mc, Python, numpy, scipy, pandas, SALib, numba and matplotlib."""
    out = {"prp3mc": __version__, "python": platform.python_version()}
    for key, dist in _PACKAGES.items():
        try:
            out[key] = metadata.version(dist)
        except metadata.PackageNotFoundError:  # pragma: no cover - all are dependencies
            out[key] = "not installed"
    return out


def sha256_file(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_record(path: str | os.PathLike) -> dict[str, str]:
    """``{"file": absolute path, "sha256": ...}`` of an input file."""
    return {"file": str(Path(path).resolve()), "sha256": sha256_file(path)}


def spec_record(spec, loaded) -> dict:
    """How a ``--geometry`` / ``--budget`` argument was resolved.

    Parameters
    ----------
    spec : str or path-like
        What the user gave: a preset name or a file path.
    loaded : object with a ``name``
        The Geometry or Budget it resolved to.

    Returns
    -------
    dict
        ``{"name": ..., "preset": name}`` for a preset, or
        ``{"name": ..., "file": path, "sha256": hash}`` for a file.
    """
    record = {"name": getattr(loaded, "name", str(spec))}
    text = str(spec)
    if Path(text).is_file():
        record.update(file_record(text))
    else:
        record["preset"] = text
    return record
