"""What a study run returns: the results of each configuration and of the whole study.

Results follow the protocol of :mod:`prp3mc._result`: frozen, read-only
arrays and mappings, a one-line ``repr`` and a tidy ``to_frame()`` in mm and
degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from .._result import freeze, short_repr
from .._version import __version__
from ..units import OUTPUT_UNITS, Z95
from ..allocation.optimum import AllocationResult
from ..montecarlo.propagation import MonteCarloResult
from ..stackup import OUTPUTS, YieldResult
from ..worstcase.envelope import WorstCaseResult
from .reader import Study, StudyConfiguration

__all__ = ["PoseSamples", "ConfigurationResult", "SkippedConfiguration", "StudyResult", "pct_se", "over_grid"]

#: Columns of :meth:`ConfigurationResult.to_frame` and :meth:`StudyResult.to_frame`.
SUMMARY_COLUMNS = ("configuration", "analysis", "output", "statistic", "aggregate", "value", "se", "unit")


def pct_se(ci: np.ndarray) -> np.ndarray:
    """Standard error of a percentile from its distribution-free 95 % interval (..., 2)."""
    return (ci[..., 1] - ci[..., 0]) / (2 * Z95)


def over_grid(values: np.ndarray, se: np.ndarray) -> dict[str, tuple[float, float]]:
    """Min, max and mean over a grid of a statistic with pose-wise standard errors.

    Returns ``{"min": (value, se), "max": (value, se), "mean": (value, se)}``:
    the min and max carry the standard error at the pose that attains them, the
    mean the mean of the pose-wise standard errors.
    """
    v, s = np.asarray(values).ravel(), np.asarray(se).ravel()
    lo, hi = int(np.argmin(v)), int(np.argmax(v))
    return {"min": (float(v[lo]), float(s[lo])), "max": (float(v[hi]), float(s[hi])),
            "mean": (float(v.mean()), float(s.mean()))}


@dataclass(frozen=True, slots=True)
class PoseSamples:
    """Monte Carlo pose errors at a few poses (the samples behind histograms).

    Attributes
    ----------
    poses : ndarray (P, 3)
        ``[x_mm, y_mm, phi_deg]``.
    labels : tuple of str
        What each pose is (``centre``, ``worst-case max``...).
    position_mm, phi_deg : ndarray (P, n)
        Position-error norm (mm) and ``|dphi|`` (deg) of each sample.
    worst_position_mm, worst_phi_deg : ndarray (P,)
        Exact worst case at each pose.
    seed, n_samples : int
    """

    poses: np.ndarray
    labels: tuple
    position_mm: np.ndarray
    phi_deg: np.ndarray
    worst_position_mm: np.ndarray
    worst_phi_deg: np.ndarray
    seed: int
    n_samples: int
    version: str = __version__

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "n_samples", "seed")

    def to_frame(self) -> pd.DataFrame:
        """Tidy samples and worst cases, one row per pose, output and value.

        Columns: ``pose`` (label), ``x_mm``, ``y_mm``, ``phi_deg``, ``output``
        (``position`` or ``phi``, the latter ``|δφ|``), ``statistic`` (``sample``
        or ``worst_case``), ``sample`` (index of the draw; <NA> for the worst
        case), ``value``, ``unit`` (mm, deg).
        """
        P, n = self.position_mm.shape
        frames = []
        for output, draws, worst in (("position", self.position_mm, self.worst_position_mm),
                                     ("phi", self.phi_deg, self.worst_phi_deg)):
            for statistic, values, per_pose in (("sample", draws, n), ("worst_case", worst[:, None], 1)):
                idx = np.repeat(np.arange(P), per_pose)
                sample = pd.array(np.tile(np.arange(n), P), dtype="Int64") if statistic == "sample" \
                    else pd.array([pd.NA] * P, dtype="Int64")
                frames.append(pd.DataFrame({
                    "pose": np.asarray(self.labels)[idx], "x_mm": self.poses[idx, 0],
                    "y_mm": self.poses[idx, 1], "phi_deg": self.poses[idx, 2], "output": output,
                    "statistic": statistic, "sample": sample,
                    "value": values.ravel(), "unit": OUTPUT_UNITS[output]}))
        return pd.concat(frames, ignore_index=True)


@dataclass(frozen=True, slots=True)
class ConfigurationResult:
    """Everything a study computed for one configuration.

    Attributes
    ----------
    configuration : StudyConfiguration
    worst_case : WorstCaseResult
        On the worst-case grid, shape (ny, nx).
    montecarlo : MonteCarloResult or None
        On the Monte Carlo grid.
    samples : PoseSamples or None
        Monte Carlo errors at the histogram poses (same samples as ``montecarlo``).
    sobol : SobolResult or None
        On the Sobol grid.
    ranking : mapping of str to DataFrame
        Per Sobol output, :func:`prp3mc.sobol.ranking.ranking` over the Sobol grid.
    allocation : AllocationResult or None
        The least-cost tolerance classes (the study's ``[allocation]``), on the allocation grid.
    allocation_front : DataFrame or None
        Its cost-accuracy Pareto front (tidy, :func:`~prp3mc.allocation.optimum.allocation_front`).
    yield_ : YieldResult or None
        The exact yield against the study's spec (``[spec]``), on the Monte Carlo grid.
    curves : tuple of ExceedanceCurve
        P(output > s) at the pose of the largest exceedance, per output with a spec (position, phi).
    """

    configuration: StudyConfiguration
    worst_case: WorstCaseResult
    montecarlo: MonteCarloResult | None = None
    samples: PoseSamples | None = None
    sobol: Any = None
    ranking: dict = field(default_factory=dict)
    allocation: AllocationResult | None = None
    allocation_front: pd.DataFrame | None = None
    yield_: YieldResult | None = None
    curves: tuple = ()

    def __post_init__(self):
        freeze(self)

    @property
    def name(self) -> str:
        return self.configuration.name

    @property
    def analyses(self) -> tuple[str, ...]:
        """The analyses that ran: ``worstcase`` and those of ``montecarlo``, ``sobol``, ``allocation``, ``yield``
        present."""
        return ("worstcase",) + tuple(a for a in ("montecarlo", "sobol", "allocation", "yield")
                                      if getattr(self, "yield_" if a == "yield" else a) is not None)

    def __repr__(self) -> str:
        return f"ConfigurationResult(name={self.name!r}, analyses={self.analyses!r})"

    def to_frame(self) -> pd.DataFrame:
        """Summary over the analyses' grids: one row per analysis, output, statistic and aggregate.

        Columns: ``configuration``, ``analysis`` (``worstcase``, ``montecarlo``,
        ``exact_yield``), ``output`` (``position``, ``phi``: ``|δφ|``, and ``any``
        for the yield: position or ``|δφ|`` beyond spec), ``statistic``
        (``worst_case``, ``p50`` ...), ``aggregate`` (``min``, ``max``, ``mean``
        over the grid), ``value``, ``se`` (0 where exact; see :func:`over_grid`),
        ``unit`` (mm, deg).

        The exact yield (with a spec, on the Monte Carlo grid) adds, per output
        (``any`` only with an orientation spec):
        ``exceed_ppm`` (unit ppm) and ``exceed_pct`` (%), the probability beyond
        spec; ``ppk`` (1; aggregate ``min`` only: infinite where P = 0);
        ``above_1ppm`` (1: the mean is the area fraction above 1 ppm);
        ``error_bound_ppm`` (aggregate ``max``); and for position and phi the exact
        quantiles ``p99.73``, ``p99.9937``, ``p99.9999`` and ``rss`` (mm, deg),
        and ``argmax_x``, ``argmax_y``, ``argmax_phi`` (aggregate ``max``: the pose
        of the largest exceedance, mm, mm, deg).
        """
        rows = []

        def add(analysis, output, statistic, values, se, unit=None, aggregates=("min", "max", "mean")):
            for aggregate, (v, s) in over_grid(values, se).items():
                if aggregate in aggregates:
                    rows.append((self.name, analysis, output, statistic, aggregate, v, s,
                                 unit or OUTPUT_UNITS[output]))

        wc = self.worst_case
        for output, values in (("position", wc.position_mm), ("phi", wc.phi_deg)):
            add("worstcase", output, "worst_case", values, np.zeros_like(values))
        if self.montecarlo is not None:
            mc = self.montecarlo
            for q, p in enumerate(mc.percentiles):
                for output, est, ci in (("position", mc.position_pct, mc.position_pct_ci),
                                        ("phi", mc.phi_pct, mc.phi_pct_ci)):
                    add("montecarlo", output, f"p{p:g}", est[..., q], pct_se(ci[..., q, :]))
        if self.yield_ is not None:
            self._yield_rows(add)
        return pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS))

    def _yield_rows(self, add) -> None:
        """The exact yield's rows of :meth:`to_frame` (see there)."""
        y = self.yield_
        zero = np.zeros(y.exceed_position.shape)
        for o in ("position",) if y.exceed_phi is None else OUTPUTS:       # any = position alone
            p = y.exceedance(o)
            add("exact_yield", o, "exceed_ppm", 1e6 * p, zero, "ppm")
            add("exact_yield", o, "exceed_pct", 100 * p, zero, "%")
            add("exact_yield", o, "ppk", y.ppk(o), zero, "1", ("min",))
            add("exact_yield", o, "above_1ppm", (p > 1e-6).astype(float), zero, "1")
            add("exact_yield", o, "error_bound_ppm", 1e6 * y.bound(o), zero, "ppm", ("max",))
            k = np.unravel_index(np.argmax(p), p.shape)
            for axis, unit in enumerate(("mm", "mm", "deg")):
                add("exact_yield", o, f"argmax_{('x', 'y', 'phi')[axis]}", np.full(p.shape, y.poses[k][axis]),
                    zero, unit, ("max",))
        for o, q, rss in (("position", y.quantile_position_mm, y.rss_position_mm), ("phi", y.quantile_phi_deg,
                                                                                    y.rss_phi_deg)):
            for j, level in enumerate(y.levels):
                add("exact_yield", o, f"p{level:g}", q[..., j], zero)
            add("exact_yield", o, "rss", rss, zero)


@dataclass(frozen=True, slots=True)
class SkippedConfiguration:
    """A configuration that gave no result, and why.

    Attributes
    ----------
    name : str
    parameters : tuple of (key, value)
        Its sweep parameters, keys as written in the study file.
    kind : str
        ``infeasible``: the combination does not assemble over its test region
        or is malformed (InfeasiblePoseError, GeometryError); ``failed``: an
        analysis raised another error.
    reason : str
        One line: the error's message (prefixed with its type for ``failed``).
    """

    name: str
    parameters: tuple
    kind: str
    reason: str

    def to_dict(self) -> dict:
        """``{"name", "parameters": {key: value}, "reason"}`` for summary.json."""
        return {"name": self.name, "parameters": dict(self.parameters), "reason": self.reason}


@dataclass(frozen=True, slots=True)
class StudyResult:
    """The results of a study run.

    Attributes
    ----------
    study : Study
    seed : int
        The study seed used (drawn if the study gave none).
    montecarlo_seed, sobol_seed : int
        Seeds derived from it, shared by all configurations.
    configurations : tuple of ConfigurationResult
        Those that ran, in the order of the study's (expanded) configurations.
    timings_s : mapping of str to float
        Compute time per analysis, summed over the configurations (on
        several workers it exceeds the wall time).
    wall_time_s : float
    skipped : tuple of SkippedConfiguration
        Configurations of a sweep that gave no result (infeasible or failed).
    scheduler : str
        What ran the configurations: ``serial``, ``local:N`` or a scheduler address.
    version : str
    allocation_seed : int or None
        Seed of the allocation's Monte Carlo confirmation (with an ``[allocation]`` table).
    """

    study: Study
    seed: int
    montecarlo_seed: int
    sobol_seed: int
    configurations: tuple
    timings_s: dict
    wall_time_s: float
    skipped: tuple = ()
    scheduler: str = "serial"
    version: str = __version__
    allocation_seed: int | None = None

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        names = tuple(c.name for c in self.configurations)
        return (f"StudyResult(study={self.study.name!r}, configurations={names!r}, seed={self.seed}, "
                f"wall_time_s={self.wall_time_s:.3g})")

    def __getitem__(self, name: str) -> ConfigurationResult:
        for c in self.configurations:
            if c.name == name:
                return c
        raise KeyError(name)

    def metadata(self) -> dict:
        """Package version, seeds, sample sizes and wall times."""
        return {"prp3mc_version": self.version, "study": self.study.name, "source": self.study.source,
                "budget": self.study.budget.name, "seed": self.seed, "montecarlo_seed": self.montecarlo_seed,
                "sobol_seed": self.sobol_seed,
                **({} if self.allocation_seed is None else {"allocation_seed": self.allocation_seed}),
                **self.study.sizes(),
                "wall_time_s": round(self.wall_time_s, 3),
                "timings_s": {k: round(v, 3) for k, v in self.timings_s.items()}}

    def to_dict(self) -> dict:
        """The content of ``summary.json``: :func:`~prp3mc.study.summary.build_summary` of this result.

        A plain dict of JSON values (the study's document, as :meth:`AllocationResult.to_dict
        <prp3mc.allocation.optimum.AllocationResult.to_dict>` is the allocation's), so it is
        written, compared (:func:`prp3mc.testing.assert_summary_close`) and read back as it is.
        """
        from .summary import build_summary          # summary formats these results: it imports this module
        return build_summary(self)

    def to_frame(self) -> pd.DataFrame:
        """Summary table of every configuration (:meth:`ConfigurationResult.to_frame`, stacked)."""
        return pd.concat([c.to_frame() for c in self.configurations], ignore_index=True)
