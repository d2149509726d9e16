"""Design sweeps: a study's ``[sweep]`` table expanded into configurations (SPEC §8).

A ``[sweep]`` table varies geometry parameters over lists; every configuration
of the study is expanded over their cartesian product::

    [sweep]
    "leg.3.a_mm" = [200, 220, 240]    # leg 3 only (legs numbered from 1)
    "leg.*.e_mm" = [10, 20, 30]       # the same value on every leg
    "leg.1.stroke_mm" = [[0, 200], [-20, 220]]

Keys name a leg parameter as in a geometry file (``a_mm``, ``alpha_deg``,
``beta_deg``, ``gamma_deg``, ``theta_deg``, ``c_mm``, ``e_mm``, ``psi_deg``,
``stroke_mm``). The expanded configuration ``k`` (1-based, in the order of
the product, the first key varying slowest) of configuration ``base`` is
named ``base.k`` (zero-padded) and records its parameters with the keys as
written in the file.

A combination may be impossible: a geometry that does not assemble over the
test region or leaves a stroke (InfeasiblePoseError), or that is malformed
(GeometryError). :meth:`Variant.build` raises those; the runner reports such
a combination by name and parameters and carries on with the others.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from ..errors import GeometryError
from ..kinematics.chain import check_poses

__all__ = ["SWEEP_KEY", "is_number", "parse_key", "parse_entry", "read_sweep", "Variant", "expand",
           "design_frame", "best_configurations"]

_ATTRIBUTE = {"a_mm": "a", "alpha_deg": "alpha", "beta_deg": "beta", "gamma_deg": "gamma", "theta_deg": "theta",
              "c_mm": "c", "e_mm": "e", "psi_deg": "psi", "stroke_mm": "stroke"}
#: Syntax of a sweep key: ``leg.<1|2|3|*>.<leg parameter>``.
SWEEP_KEY = re.compile(rf"^leg\.([123*])\.({'|'.join(_ATTRIBUTE)})$")


def parse_key(key: str) -> tuple[tuple[int, ...], str]:
    """The legs (0-based) and the Geometry attribute a sweep key names.

    >>> parse_key("leg.*.e_mm")
    ((0, 1, 2), 'e')
    >>> parse_key("leg.3.a_mm")
    ((2,), 'a')

    Raises
    ------
    GeometryError
        If ``key`` is not ``leg.<1|2|3|*>.<leg parameter>``.
    """
    match = SWEEP_KEY.match(key)
    if not match:
        raise GeometryError(f"sweep key {key!r} must read leg.<1|2|3|*>.<parameter> with a parameter among "
                            f"{', '.join(_ATTRIBUTE)}")
    leg, name = match.groups()
    return ((0, 1, 2) if leg == "*" else (int(leg) - 1,)), _ATTRIBUTE[name]


def is_number(v) -> bool:
    """A finite int or float (not a bool), as TOML gives them."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def parse_entry(key: str, values: Any) -> tuple[tuple[int, ...], str, tuple]:
    """Legs (0-based), Geometry attribute and values of one ``[sweep]`` entry.

    Raises
    ------
    GeometryError
        One line: the key is malformed (or unquoted, so TOML read a table),
        or the values are not a non-empty array of distinct finite numbers
        (``[lo, hi]`` pairs for ``stroke_mm``).
    """
    if isinstance(values, dict):  # leg.3.a_mm = [...] unquoted is a TOML dotted key: a nested table
        raise GeometryError(f'sweep keys must be quoted, as "leg.3.a_mm" = [...], got a table {key!r}')
    legs, attribute = parse_key(key)
    pair = attribute == "stroke"  # values are [lo, hi]
    ok = (lambda v: isinstance(v, list) and len(v) == 2 and all(map(is_number, v))) if pair else is_number
    if not isinstance(values, list) or not values or not all(ok(v) for v in values):
        raise GeometryError(f"sweep {key!r} must be a non-empty array of "
                            f"{'[lo, hi] pairs' if pair else 'finite numbers'}, got {values!r}")
    if len({repr(v) for v in values}) != len(values):
        raise GeometryError(f"sweep {key!r} lists a value twice: {values!r}")
    return legs, attribute, tuple(tuple(v) if pair else v for v in values)


def read_sweep(reader, table: dict) -> tuple:
    """The ``[sweep]`` table as ``((key, values), ...)``, mistakes failing through the study ``reader``.

    ``reader.fail(path, reason)`` raises the study file's ``FILE:LINE: reason``;
    besides :func:`parse_entry`'s checks, no leg parameter may be set by two keys.
    """
    out, legs = [], {}
    for key, values in table.items():
        path = ("sweep", key)
        try:
            which, attribute, values = parse_entry(key, values)
        except GeometryError as exc:
            reader.fail(path, str(exc))
        for i in which:
            if (i, attribute) in legs:
                reader.fail(path, f"sweep {key!r} sets leg {i + 1}'s {attribute} again (also set by "
                            f"{legs[i, attribute]!r})")
            legs[i, attribute] = key
        out.append((key, values))
    return tuple(out)


def apply(geometry, parameters: dict[str, Any]):
    """``geometry`` with the sweep ``parameters`` ``{key: value}`` set (degrees, mm)."""
    changes: dict[str, list] = {}
    for key, value in parameters.items():
        legs, attribute = parse_key(key)
        current = changes.setdefault(attribute, list(getattr(geometry, attribute)))
        for i in legs:
            current[i] = value
    return geometry.replace(**changes)


@dataclass(frozen=True, slots=True)
class Variant:
    """One configuration of a (possibly swept) study, not yet checked.

    Attributes
    ----------
    index : int
        Position among the study's expanded configurations (0-based).
    name : str
    base : StudyConfiguration
        The configuration of the study file it comes from.
    parameters : tuple of (key, value)
        Its sweep parameters in the order of the ``[sweep]`` table (empty
        without a sweep).
    check_grid : (nx, ny)
        Grid on which the test region must be feasible (the worst-case grid).
    """

    index: int
    name: str
    base: Any
    parameters: tuple = ()
    check_grid: tuple = (2, 2)

    def build(self):
        """The StudyConfiguration; GeometryError or InfeasiblePoseError if the combination is impossible.

        Without parameters the base configuration is returned as it is (the
        study reader already checked it).
        """
        if not self.parameters:
            return self.base
        config = replace(self.base, name=self.name, geometry=apply(self.base.geometry, dict(self.parameters)),
                         parameters=self.parameters)
        check_poses(config.geometry, config.region.grid(self.check_grid))
        if config.poses is not None:
            check_poses(config.geometry, np.asarray(config.poses))
        return config


def expand(study) -> tuple[Variant, ...]:
    """Every configuration a study runs: its configurations, each expanded over the sweep's product.

    Parameters
    ----------
    study : Study

    Returns
    -------
    tuple of Variant
        Without a sweep, one variant per configuration, with its own name and
        no parameters.
    """
    if not study.sweep:
        return tuple(Variant(k, c.name, c) for k, c in enumerate(study.configurations))
    keys = [key for key, _ in study.sweep]
    combos = list(itertools.product(*(values for _, values in study.sweep)))
    width = len(str(len(combos)))
    variants = []
    for base in study.configurations:
        for k, combo in enumerate(combos, start=1):
            variants.append(Variant(len(variants), f"{base.name}.{k:0{width}d}", base,
                                    tuple(zip(keys, combo)), study.worstcase_grid))
    return tuple(variants)


def _top_sobol(c) -> list[dict]:
    rows = []
    for output, frame in c.ranking.items():
        top = frame.sort_values("ST", ascending=False).iloc[0]
        rows.append({"analysis": "sobol", "output": output, "statistic": "ST_top", "value": float(top["ST"]),
                     "unit": "1", "input": top["name"]})
    return rows


def design_frame(result, percentile: float = 99.73) -> pd.DataFrame:
    """Figures of merit of every configuration against its sweep parameters, one row per merit.

    Columns: ``configuration``, one column per sweep key (as written),
    ``analysis`` (``worstcase``, ``montecarlo``, ``sobol``), ``output``
    (``position``, ``phi``), ``statistic`` (``worst_case``, ``p99.73``, or
    ``ST_top``: the largest total Sobol index), ``value`` (the maximum over
    the test region; for ``ST_top`` the index aggregated over the Sobol grid),
    ``unit`` (mm, deg, 1) and ``input`` (the input or group with the largest
    ST; empty otherwise). The Monte Carlo percentile is ``percentile`` if the
    study computed it, else its highest.
    """
    keys = [key for key, _ in result.study.sweep]
    rows = []
    for c in result.configurations:
        frame = c.to_frame().query("aggregate == 'max'")
        if c.montecarlo is not None:
            pcts = c.montecarlo.percentiles
            keep = f"p{(percentile if percentile in pcts else pcts[-1]):g}"
            frame = frame[(frame["analysis"] != "montecarlo") | (frame["statistic"] == keep)]
        merits = frame[["analysis", "output", "statistic", "value", "unit"]].to_dict("records") + _top_sobol(c)
        params = dict(c.configuration.parameters)
        for merit in merits:
            rows.append({"configuration": c.name, **{k: params.get(k) for k in keys},
                         **merit, "input": merit.get("input", "")})
    columns = ["configuration", *keys, "analysis", "output", "statistic", "value", "unit", "input"]
    return pd.DataFrame(rows, columns=columns)


def best_configurations(frame: pd.DataFrame, k: int = 3) -> list[str]:
    """The ``k`` configurations with the lowest worst-case position error over their region.

    ``frame`` is a :func:`design_frame`.
    """
    worst = frame.query("analysis == 'worstcase' and output == 'position'")
    return worst.sort_values(["value", "configuration"])["configuration"].head(k).tolist()
