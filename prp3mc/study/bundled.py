"""The studies that ship with prp3mc: their folder and names (no study is read, nothing heavy is imported:
``prp3mc study --help`` lists them)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["STUDIES_DIR", "bundled_studies"]


def _studies_dir() -> Path:
    """The bundled studies: ``studies/`` of the source tree, installed as ``prp3mc/studies``."""
    package = Path(__file__).resolve().parent.parent          # prp3mc/
    installed = package / "studies"
    return installed if installed.is_dir() else package.parent / "studies"


#: Folder of the bundled studies.
STUDIES_DIR = _studies_dir()


def bundled_studies() -> tuple[str, ...]:
    """Names of the bundled studies."""
    return tuple(sorted(p.stem for p in STUDIES_DIR.glob("*.toml"))) if STUDIES_DIR.is_dir() else ()
