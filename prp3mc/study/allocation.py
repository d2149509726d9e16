"""A study's tolerance allocation: its ``[allocation]`` table, its run per configuration, its summary.

The table (layout in :mod:`prp3mc.study.reader`) names a classes menu and an
accuracy spec; for every configuration it applies to, the study runs
:func:`prp3mc.allocate` over the configuration's geometry and test region
(gridded like the worst case unless the table gives a grid, at the region's
orientation, unbounded laws bounded by ``[worstcase] k_sigma``) and, with
``front = true``, :func:`~prp3mc.allocation.optimum.allocation_front`
on the same poses. The allocation's budget is the classes' laws, as in
``prp3mc allocate``, with the study budget's ``[effects]`` held fixed (its
inputs play no part).

Randomness: the Monte Carlo confirmation of a percentile spec draws from
``child_seed(study seed, 3)`` (stream 3; Monte Carlo is 1, Sobol 2), the
same seed for every configuration.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import pandas as pd

from ..errors import Prp3mcError
from ..kinematics.chain import check_poses
from ..allocation.optimum import AllocationResult, allocate, allocation_front, front_records
from ..allocation.classes import ClassMenu
from ..units import MM2UM, Z95

__all__ = ["AllocationSpec", "ALLOCATION_STREAM", "read_allocation", "run_allocation", "allocation_summary"]

#: Stream key of the allocation's Monte Carlo confirmation under the study seed.
ALLOCATION_STREAM = 3
_KEYS = {"classes", "spec_position_um", "spec_phi_arcsec", "spec_percentile", "samples", "grid", "front",
         "configurations"}
_DEFAULT_SAMPLES = 20_000
_REDUCED = {"grid": 21, "samples": 1 << 14}


@dataclass(frozen=True, slots=True)
class AllocationSpec:
    """A validated ``[allocation]`` table.

    Attributes
    ----------
    classes : ClassMenu
    classes_source : str
        The menu as the file names it (a preset name or a path).
    spec_position_um, spec_phi_arcsec : float or None
        Bounds on the worst-case position error (µm; with ``spec_percentile``
        on that percentile) and on the worst-case ``|δφ|`` (arcsec).
    spec_percentile : float or None
    samples : int
        Monte Carlo samples confirming a percentile spec.
    grid : (nx, ny) or None
        Poses of the region; None: the study's worst-case grid.
    front : bool
        Also sweep the cost-accuracy Pareto front.
    configurations : tuple of str or None
        The configurations it runs for; None: every configuration.
    """

    classes: ClassMenu
    classes_source: str
    spec_position_um: float | None = None
    spec_phi_arcsec: float | None = None
    spec_percentile: float | None = None
    samples: int = _DEFAULT_SAMPLES
    grid: tuple | None = None
    front: bool = True
    configurations: tuple | None = None

    def applies_to(self, name: str) -> bool:
        """Whether the allocation runs for the configuration ``name``."""
        return self.configurations is None or name in self.configurations

    @property
    def front_output(self) -> str:
        """The output the front is swept in: the position error, or ``|δφ|`` with only a phi spec."""
        return "position" if self.spec_position_um is not None else "phi"

    def reduced(self) -> "AllocationSpec":
        """Test size: grid and Monte Carlo samples capped (as :meth:`Study.reduced`)."""
        grid = None if self.grid is None else tuple(min(n, _REDUCED["grid"]) for n in self.grid)
        return replace(self, grid=grid, samples=min(self.samples, _REDUCED["samples"]))

    def sizes(self, worstcase_grid: tuple) -> dict:
        """Grid and sample sizes (for metadata)."""
        out: dict[str, Any] = {"allocation_grid": list(self.grid or worstcase_grid)}
        if self.spec_percentile is not None:
            out["allocation_samples"] = self.samples
        return out


# ----------------------------------------------------------------- reading
def _positive(reader, table: dict, key: str):
    value = reader.get(table, ("allocation", key), "number")
    if value is not None and value <= 0:
        reader.fail(("allocation", key), f"allocation.{key} must be > 0, got {value}")
    return None if value is None else float(value)


def read_allocation(reader, doc: dict, configurations: tuple, worstcase_grid: tuple,
                    k_sigma: float | None) -> AllocationSpec | None:
    """Validate the ``[allocation]`` table of a parsed study, or None without one.

    ``reader`` is the study reader (its ``get``, ``fail``, ``unknown``,
    ``grid``, ``samples`` and ``load`` point mistakes at their lines);
    ``configurations`` are the parsed StudyConfigurations.
    """
    if "allocation" not in doc:
        return None
    p = ("allocation",)
    table = reader.get(doc, p, "table")
    reader.unknown(table, _KEYS, p, "[allocation]")
    if "classes" not in table:
        reader.fail(p, "[allocation] needs classes = \"example\" or a classes TOML file (prp3mc init classes)")
    source = reader.get(table, p + ("classes",), "str")
    menu = reader.load(p + ("classes",), "classes", ClassMenu.load, source)
    for family, classes in menu.families.items():
        for c in classes:
            try:
                c.law.bounds(k_sigma)
            except Prp3mcError as exc:
                reader.fail(p + ("classes",), f"classes {source!r}: [{family}] class {c.name!r}: {exc} "
                            f"(set [worstcase] k_sigma)")
    position, phi = _positive(reader, table, "spec_position_um"), _positive(reader, table, "spec_phi_arcsec")
    if position is None and phi is None:
        reader.fail(p, "[allocation] needs spec_position_um (µm), spec_phi_arcsec (arcsec) or both")
    percentile = reader.get(table, p + ("spec_percentile",), "number")
    if percentile is not None:
        if not 0 < percentile < 100:
            reader.fail(p + ("spec_percentile",), f"allocation.spec_percentile must lie in (0, 100), "
                        f"got {percentile}")
        if position is None:
            reader.fail(p + ("spec_percentile",), "a percentile spec bounds the position error: "
                        "give spec_position_um too")
        percentile = float(percentile)
    if "samples" in table and percentile is None:
        reader.fail(p + ("samples",), "allocation.samples sizes the Monte Carlo confirmation of a "
                    "percentile spec: give spec_percentile too")
    samples = reader.samples(table, p + ("samples",), _DEFAULT_SAMPLES)
    grid = reader.grid(table, p + ("grid",), None)
    front = table.get("front", True)
    if not isinstance(front, bool):
        reader.fail(p + ("front",), f"allocation.front must be true or false, got {front!r}")
    names = _configurations(reader, table, tuple(c.name for c in configurations))
    for c in configurations:
        if grid is not None and (names is None or c.name in names):
            try:
                check_poses(c.geometry, c.region.grid(grid))
            except Prp3mcError as exc:
                reader.fail(p + ("grid",), f"configuration {c.name!r}: the allocation grid leaves the "
                            f"workspace: {exc}")
    return AllocationSpec(classes=menu, classes_source=source, spec_position_um=position, spec_phi_arcsec=phi,
                          spec_percentile=percentile, samples=samples, grid=grid, front=front,
                          configurations=names)


def _configurations(reader, table: dict, known: tuple) -> tuple | None:
    path = ("allocation", "configurations")
    names = reader.get(table, path, "list")
    if names is None:
        return None
    if not names or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
        reader.fail(path, f"allocation.configurations must list distinct configuration names, got {names!r}")
    unknown = [n for n in names if n not in known]
    if unknown:
        reader.fail(path, f"allocation.configurations: no configuration named {unknown[0]!r} "
                    f"(configurations: {', '.join(known)})")
    return tuple(names)


# ----------------------------------------------------------------- running
def run_allocation(config, spec: AllocationSpec, worstcase_grid: tuple, k_sigma: float | None,
                   seed: int, budget=None) -> dict:
    """Allocate for one configuration: ``{"allocation": AllocationResult, "allocation_front": DataFrame or None}``.

    ``seed`` confirms a percentile spec (the study's allocation seed);
    ``budget``'s effects stay fixed (the study budget).
    """
    poses = config.region.grid(spec.grid or worstcase_grid).reshape(-1, 3)
    result = allocate(config.geometry, spec.classes, poses, spec_position_um=spec.spec_position_um,
                      spec_phi_arcsec=spec.spec_phi_arcsec, spec_percentile=spec.spec_percentile,
                      k_sigma=k_sigma, n_samples=spec.samples, rng=seed, budget=budget)
    front = None
    if spec.front:
        side = {"spec_phi_arcsec": spec.spec_phi_arcsec} if spec.front_output == "position" else {}
        front = allocation_front(config.geometry, spec.classes, poses, output=spec.front_output,
                                 k_sigma=k_sigma, budget=budget, **side)
    return {"allocation": result, "allocation_front": front}


# ----------------------------------------------------------------- summary.json
def allocation_summary(result: AllocationResult, front: pd.DataFrame | None) -> dict:
    """The ``allocation`` entry of a configuration in ``summary.json`` (µm, arcsec).

    Exact quantities are plain numbers: ``cost``, ``choice``, the worst case of
    the chosen classes over the region (``worst_case_position_um``,
    ``worst_case_phi_arcsec``), ``feasible``, ``spec``, ``binding``,
    ``binding_poses`` and, with a front, ``front`` (cost and worst cases of
    each Pareto point). A percentile spec adds ``statistical``: the screened
    bound (exact) and the Monte Carlo percentile and 95 % upper bound at the
    binding pose as ``{"value", "se"}`` (se: the interval's upper half-width
    / 1.96). Seeds and search effort are run metadata, not here.
    """
    doc = result.to_dict()
    out = {key: doc[key] for key in ("cost", "choice", "worst_case_position_um", "worst_case_phi_arcsec",
                                     "feasible", "spec", "binding", "binding_poses")}
    if result.statistical is not None:
        st = result.statistical
        est, high = MM2UM * st["percentile_mm"], MM2UM * st["ci_high_mm"]
        se = (high - est) / Z95
        out["statistical"] = {"percentile": st["percentile"], "screen_um": doc["statistical"]["screen_um"],
                              "percentile_um": {"value": est, "se": se}, "ci95_high_um": {"value": high, "se": se},
                              "n_samples": st["n_samples"], "confirmed": st["confirmed"]}
    if front is not None:
        out["front"] = front_records(front)
    return out

