"""The protocol every result object follows.

Results are frozen dataclasses whose arrays are read-only and whose mappings
are read-only (:class:`FrozenDict`), so a result cannot be changed after it is made.
``to_frame()`` gives a tidy DataFrame in one vocabulary:

- pose columns ``x_mm``, ``y_mm``, ``phi_deg`` (the commanded pose);
- ``output``: ``x``, ``y``, ``phi`` or ``position`` (percentiles and maxima of
  ``phi`` are of |δφ|);
- ``statistic``: what the value is (``mean``, ``std``, ``p95``, ``max``,
  ``worst_case``, ``S1``, ``ST`` ...);
- ``value`` and ``unit`` in boundary units (mm, deg, 1), ``se`` where there is one;
- ``ci_low``, ``ci_high`` and ``level`` for confidence intervals
  (``conf_int(level=0.95)`` returns exactly such a frame).

``repr`` is one short line: shapes and the few scalars that identify the run.
"""

from __future__ import annotations

import dataclasses
import functools
from types import MappingProxyType

import numpy as np
import pandas as pd

__all__ = ["FrozenDict", "freeze", "short_repr", "pose_columns", "name_columns", "interval_frame", "POSE_COLUMNS",
           "CI_COLUMNS"]

POSE_COLUMNS = ("x_mm", "y_mm", "phi_deg")
CI_COLUMNS = ("ci_low", "ci_high", "level")


class FrozenDict(dict):
    """A read-only dict: every mutating method raises TypeError. Pickles (unlike a mappingproxy)."""

    def _readonly(self, *args, **kwargs):
        raise TypeError(f"{type(self).__name__} is read-only")

    __setitem__ = __delitem__ = __ior__ = _readonly
    clear = pop = popitem = setdefault = update = _readonly

    def __reduce__(self):
        return (type(self), (dict(self),))

    def __hash__(self):
        return hash(tuple(self.items()))


def _frozen(value):
    if isinstance(value, np.ndarray):
        if value.flags.writeable:
            value = value.view()
            value.setflags(write=False)
        return value
    if isinstance(value, (FrozenDict, MappingProxyType)):
        return value
    if isinstance(value, dict):
        return FrozenDict({k: _frozen(v) for k, v in value.items()})
    if isinstance(value, list):
        return tuple(_frozen(v) for v in value)
    return value


def freeze(obj) -> None:
    """Make every ndarray field of a frozen dataclass read-only and every dict a :class:`FrozenDict`.

    Call at the end of ``__post_init__``. Arrays are replaced by read-only
    views (no copy); dicts by FrozenDicts of frozen values (they pickle, so
    results travel to Dask workers and back).
    """
    for name in _field_names(type(obj)):
        value = getattr(obj, name)
        if type(value) in _IMMUTABLE or (type(value) is np.ndarray and not value.flags.writeable):
            continue            # (the common cases first: a small result's freeze is a good part of its cost)
        frozen = _frozen(value)
        if frozen is not value:
            object.__setattr__(obj, name, frozen)


#: Field types that :func:`freeze` leaves as they are.
_IMMUTABLE = frozenset({str, int, float, bool, type(None), FrozenDict})


def thawed(value):
    """A frozen value as plain JSON-ready Python: mappings to dicts, tuples to lists (:func:`freeze` undone)."""
    if isinstance(value, (dict, MappingProxyType)):
        return {k: thawed(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [thawed(v) for v in value]
    return value


@functools.cache
def _field_names(cls) -> tuple[str, ...]:
    """The field names of dataclass ``cls``, read once (a small result's whole freeze costs less than
    ``dataclasses.fields``)."""
    return tuple(f.name for f in dataclasses.fields(cls))


def _describe(value) -> str:
    if isinstance(value, np.ndarray):
        return f"array{value.shape}" if value.ndim else f"{value.item():.6g}"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (str, int, bool)) or value is None:
        return repr(value)
    if hasattr(value, "name") and isinstance(getattr(value, "name"), str):
        return repr(value.name)
    return type(value).__name__


def short_repr(obj, *names: str) -> str:
    """``Name(field=..., ...)`` showing only ``names``; arrays appear as their shapes."""
    parts = ", ".join(f"{n}={_describe(getattr(obj, n))}" for n in names)
    return f"{type(obj).__name__}({parts})"


def pose_columns(poses: np.ndarray, repeat: int = 1) -> dict[str, np.ndarray]:
    """The pose columns of a tidy frame: each flattened pose repeated ``repeat`` times."""
    flat = np.asarray(poses, dtype=float).reshape(-1, 3)
    flat = np.repeat(flat, repeat, axis=0)
    return {c: flat[:, k] for k, c in enumerate(POSE_COLUMNS)}


def name_columns(poses: np.ndarray, outputs: tuple, names: tuple, kinds: tuple) -> dict[str, np.ndarray]:
    """Pose, ``output``, ``name`` and ``kind`` columns, one row per pose, output and name (C order of
    an (..., O, K) array of indices)."""
    n = int(np.prod(np.shape(poses)[:-1], dtype=int))
    O, K = len(outputs), len(names)
    return {**pose_columns(poses, O * K), "output": np.tile(np.repeat(outputs, K), n),
            "name": np.tile(names, n * O), "kind": np.tile(kinds, n * O)}


def interval_frame(frame: pd.DataFrame, low, high, level: float) -> pd.DataFrame:
    """Add ``ci_low``, ``ci_high`` and ``level`` columns to ``frame`` (in place) and return it."""
    frame["ci_low"] = np.asarray(low, dtype=float)
    frame["ci_high"] = np.asarray(high, dtype=float)
    frame["level"] = float(level)
    return frame
