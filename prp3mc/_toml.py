"""Reading and writing the small TOML documents prp3mc uses.

Reading uses the standard library's :mod:`tomllib`; writing covers what
prp3mc writes (tables, arrays of tables, numbers, strings, booleans and flat
arrays of those), so no extra dependency is needed.
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from pathlib import Path
from typing import Any

from .errors import InputFileError

__all__ = ["load_toml", "loads_toml", "dumps_toml", "load_spec", "read_text_file"]


def loads_toml(text: str, source: str = "<string>") -> dict[str, Any]:
    """Parse TOML text; a syntax error becomes one :class:`InputFileError` line."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputFileError(f"{source}: malformed TOML: {exc}") from None


def read_text_file(path: str | os.PathLike, error: type[Exception] = InputFileError, what: str = "file") -> str:
    """The UTF-8 text of ``path`` (a byte-order mark skipped); a missing or unreadable file raises ``error`` naming it."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise error(f"{path}: no such {what}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read: {exc}") from None


def load_toml(path: str | os.PathLike) -> dict[str, Any]:
    """Read a TOML file, naming the file in any error."""
    return loads_toml(read_text_file(path), str(path))


def _scalar(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_scalar(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_scalar(v)}" for k, v in value.items()) + "}"
    if hasattr(value, "item"):  # numpy scalar
        return _scalar(value.item())
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


#: Characters a TOML basic string must escape: the backslash, the quote and the control characters.
_ESCAPE = re.compile(r'[\\"\x00-\x1f\x7f]')
_SHORT = {"\\": "\\\\", '"': '\\"', "\n": "\\n", "\t": "\\t", "\r": "\\r", "\b": "\\b", "\f": "\\f"}


def _string(value: str) -> str:
    """A TOML basic string holding ``value`` exactly (control characters escaped; non-ASCII as it is).

    A lone surrogate (a file name that is not UTF-8, as Python decodes it)
    has no TOML form: it is written as its ``\\udcXX`` escape text.
    """
    value = value.encode("utf-8", "backslashreplace").decode("utf-8")
    return '"' + _ESCAPE.sub(lambda m: _SHORT.get(m.group(), f"\\u{ord(m.group()):04x}"), value) + '"'


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _string(key)   # bare keys are ASCII only


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _emit(table: dict[str, Any], prefix: str, lines: list[str]) -> None:
    for key, value in table.items():
        if not isinstance(value, dict) and not _is_table_array(value):
            lines.append(f"{_key(key)} = {_scalar(value)}")
    for key, value in table.items():
        name = f"{prefix}.{_key(key)}" if prefix else _key(key)
        if isinstance(value, dict):
            lines.extend(["", f"[{name}]"])
            _emit(value, name, lines)
        elif _is_table_array(value):
            for item in value:
                lines.extend(["", f"[[{name}]]"])
                _emit(item, name, lines)


def dumps_toml(document: dict[str, Any], header: str = "") -> str:
    """Serialise a nested dict to TOML text (round-trips through ``loads_toml``)."""
    lines = [f"# {line}" for line in header.splitlines()]
    _emit(document, "", lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def load_spec(cls, spec, presets: dict):
    """``spec`` as an instance of ``cls``: itself, a preset name, or a TOML file path.

    ``cls`` provides ``from_preset`` and ``from_toml``; an unknown name that
    is not a file is reported by ``from_preset`` with the known presets.
    """
    if isinstance(spec, cls):
        return spec
    text = str(spec)
    if text not in presets and (text.endswith(".toml") or Path(text).exists()):
        return cls.from_toml(spec)
    return cls.from_preset(text)
