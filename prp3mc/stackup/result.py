"""The exact yield of a batch of poses against a specification: :class:`YieldResult`."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import special

from .._result import freeze, pose_columns, short_repr
from .._version import __version__
from ..errors import ParameterError
from ..units import DEG2ARCSEC, MM2UM, PPM
from .lattice import LEVELS

__all__ = ["YieldResult", "ppk", "region_summary", "PPM", "QUANTILE_LEVELS", "OUTPUTS"]

#: The probabilities of the quantiles :func:`~prp3mc.stackup.exact_yield` reports, in %: 99.73 and 99.9937
#: (3 and 4 sd of a normal law, two-sided: Cpk 1 and 1.33) and 99.9999 (1 ppm). The series solves for the
#: fractions :data:`prp3mc.stackup.lattice.LEVELS`, which these are in %.
QUANTILE_LEVELS = tuple(round(100.0 * v, 10) for v in LEVELS)
#: The outputs of an exceedance: the position error, ``|dphi|``, and either.
OUTPUTS = ("position", "phi", "any")


def ppk(exceed) -> np.ndarray:
    """The one-sided process capability equivalent to an exceedance P: Phi^-1(1 - P) / 3 (inf at P = 0)."""
    p = np.clip(np.asarray(exceed, dtype=float), 0.0, 1.0)
    with np.errstate(divide="ignore"):
        return special.ndtri(1.0 - p) / 3.0


def region_summary(exceed, poses, threshold: float = 1e-6) -> dict:
    """A position exceedance (...) over its poses (..., 3): ``max_exceed_position_ppm``,
    ``mean_exceed_position_ppm``, ``area_fraction_above_1ppm`` (the share of poses above ``threshold``) and
    ``argmax_pose`` (x mm, y mm, phi deg)."""
    flat = np.asarray(exceed, dtype=float).reshape(-1)
    k = int(np.argmax(flat))
    return {"max_exceed_position_ppm": PPM * float(flat[k]),
            "mean_exceed_position_ppm": PPM * float(flat.mean()),
            "area_fraction_above_1ppm": float(np.mean(flat > threshold)),
            "argmax_pose": [float(v) for v in np.reshape(poses, (-1, 3))[k]]}


@dataclass(frozen=True, slots=True, repr=False)
class YieldResult:
    """The exact distribution of the linear model's pose error against a spec, per pose.

    Shapes: ``...`` is the batch shape of ``poses``. Probabilities are
    absolute (multiply by 1e6 for ppm); every one comes with a bound of its
    absolute error, which the computation guarantees (:attr:`method`).

    Attributes
    ----------
    poses : ndarray (..., 3)
        ``[x_mm, y_mm, phi_deg]``.
    spec_position_mm : float
        S: the position spec, ``|(dx, dy)|`` <= S.
    spec_phi_deg : float or None
        Z: the orientation spec, ``|dphi|`` <= Z.
    exceed_position, bound_position : ndarray (...)
        P(``|(dx, dy)|`` > S) and the bound of its error.
    exceed_phi, bound_phi : ndarray (...) or None
        P(``|dphi|`` > Z) and its bound (None without an orientation spec).
    exceed_any, bound_any : ndarray (...)
        P(position > S or ``|dphi|`` > Z) and its bound (the position's without an orientation spec).
    levels : tuple of float
        The quantiles' probabilities, in %: :data:`QUANTILE_LEVELS` (99.73, 99.9937, 99.9999), or () without
        quantiles.
    quantile_position_mm, quantile_position_err_mm : ndarray (..., Q) or None
        Quantiles of the position error's norm and bounds of their errors.
    quantile_phi_deg, quantile_phi_err_deg : ndarray (..., Q) or None
        Quantiles of ``|dphi|`` and bounds of their errors.
    worst_position_mm, worst_phi_deg : ndarray (...)
        The exact worst case of the linear model (NaN when a law is unbounded: normal).
    rss_position_mm, rss_phi_deg : ndarray (...)
        Root-sum-square stack: ``|centre|`` + sqrt(sum_t (``|c_t|`` h_t)²), h_t the half-width of term t's
        interval (3 sd for a normal law), c_t its column: the tolerance engineer's RSS.
    bracketed_any : ndarray (...) bool
        Poses whose ``exceed_any`` is the midpoint of [max(P_pos, P_phi), P_pos + P_phi] (the joint
        series could not be certified there: a leg without a continuous law); its bound covers the bracket.
    lattice_points : dict of str to ndarray (...)
        Lattice points each series walked, per channel (``position``, ``phi``, ``any``).
    target : float
        The error bound asked for (absolute probability).
    method : str
    version : str
    wall_time_s : float
    """

    poses: np.ndarray
    spec_position_mm: float
    spec_phi_deg: float | None
    exceed_position: np.ndarray
    bound_position: np.ndarray
    exceed_phi: np.ndarray | None
    bound_phi: np.ndarray | None
    exceed_any: np.ndarray
    bound_any: np.ndarray
    levels: tuple
    quantile_position_mm: np.ndarray | None
    quantile_position_err_mm: np.ndarray | None
    quantile_phi_deg: np.ndarray | None
    quantile_phi_err_deg: np.ndarray | None
    worst_position_mm: np.ndarray
    worst_phi_deg: np.ndarray
    rss_position_mm: np.ndarray
    rss_phi_deg: np.ndarray
    bracketed_any: np.ndarray
    lattice_points: dict
    target: float
    method: str
    version: str = __version__
    wall_time_s: float = field(default=float("nan"), compare=False)

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "poses", "spec_position_mm", "spec_phi_deg", "target")

    @property
    def error_bound(self) -> np.ndarray:
        """The largest bound of the exceedances (:attr:`outputs`), (...)."""
        return functools.reduce(np.maximum, (self.bound(o) for o in self.outputs))

    def ppk(self, output: str = "position") -> np.ndarray:
        """The one-sided Ppk equivalent to an exceedance: Phi^-1(1 - P) / 3 (``position``, ``phi``, ``any``)."""
        return ppk(self.exceedance(output))

    @property
    def outputs(self) -> tuple[str, ...]:
        """The outputs :meth:`exceedance` and :meth:`bound` take: :data:`OUTPUTS`, without ``phi`` when there is
        no orientation spec (``any`` is then the position's)."""
        return OUTPUTS if self.exceed_phi is not None else ("position", "any")

    def exceedance(self, output: str) -> np.ndarray:
        """P(output beyond its spec), (...): ``output`` one of :data:`OUTPUTS` (``position``, ``phi``, ``any``)."""
        return self._output(output)[0]

    def bound(self, output: str) -> np.ndarray:
        """The bound of the absolute error of :meth:`exceedance` (``output``), (...)."""
        return self._output(output)[1]

    def _output(self, output: str) -> tuple[np.ndarray, np.ndarray]:
        """(exceedance, bound) of ``output``; KeyError for an unknown one, or ``phi`` without an orientation spec."""
        if output not in OUTPUTS:
            raise KeyError(f"no output {output!r}; choose from {', '.join(OUTPUTS)}")
        if output not in self.outputs:
            raise KeyError("no orientation spec: exceed_phi was not computed")
        return getattr(self, f"exceed_{output}"), getattr(self, f"bound_{output}")

    def region_summary(self, threshold: float = 1e-6) -> dict:
        """The position exceedance over the poses (:func:`region_summary`)."""
        return region_summary(self.exceed_position, self.poses, threshold)

    def to_frame(self) -> pd.DataFrame:
        """Tidy table: x_mm, y_mm, phi_deg, output, statistic, value, unit, error_bound, method.

        Statistics: ``exceed`` (outputs position, phi, any; unit 1), the quantiles ``p99.73``...
        (position in mm, phi of ``|dphi|`` in deg), ``worst_case`` and ``rss``.
        """
        cols = pose_columns(self.poses)
        n = cols["x_mm"].size
        rows = []

        def add(output, statistic, value, unit, bound):
            rows.append(pd.DataFrame({**cols, "output": output, "statistic": statistic,
                                      "value": np.asarray(value, dtype=float).reshape(n), "unit": unit,
                                      "error_bound": np.asarray(bound, dtype=float).reshape(n),
                                      "method": self.method}))

        for output in self.outputs:
            add(output, "exceed", self.exceedance(output), "1", self.bound(output))
        for q, level in enumerate(self.levels):
            if self.quantile_position_mm is not None:
                add("position", f"p{level:g}", self.quantile_position_mm[..., q], "mm",
                    self.quantile_position_err_mm[..., q])
            if self.quantile_phi_deg is not None:
                add("phi", f"p{level:g}", self.quantile_phi_deg[..., q], "deg", self.quantile_phi_err_deg[..., q])
        add("position", "worst_case", self.worst_position_mm, "mm", np.zeros(n))
        add("phi", "worst_case", self.worst_phi_deg, "deg", np.zeros(n))
        add("position", "rss", self.rss_position_mm, "mm", np.zeros(n))
        add("phi", "rss", self.rss_phi_deg, "deg", np.zeros(n))
        return pd.concat(rows, ignore_index=True)

    def pose_record(self, index=()) -> dict:
        """The SPEC §9 figures at one pose (µm, arcsec, ppm), as ``prp3mc yield --json`` prints them.

        ``index`` selects the pose in the batch shape ``...`` (``()`` for a single pose, ``(i, j)`` on a
        grid); an index that is not one pose's raises :class:`~prp3mc.errors.ParameterError`.
        """
        shape = np.shape(self.exceed_position)
        try:
            one = np.ndim(np.asarray(self.exceed_position)[index]) == 0
        except (IndexError, TypeError, ValueError):
            one = False
        if not one:
            raise ParameterError(f"pose_record: index {index!r} is not one pose of the batch {shape}: give one "
                                 f"index per axis, e.g. {(0,) * len(shape)}")

        def val(a):
            return None if a is None else float(np.asarray(a)[index])

        def quantiles(a, scale):
            if a is None:
                return None
            return {f"p{lv:g}": scale * float(np.asarray(a)[index][q]) for q, lv in enumerate(self.levels)}

        def finite(v):
            return v if v is not None and np.isfinite(v) else None

        bound = float(self.error_bound[index])
        record = {
            "exceed_position_ppm": PPM * val(self.exceed_position),
            "exceed_phi_ppm": None if self.exceed_phi is None else PPM * val(self.exceed_phi),
            "exceed_any_ppm": PPM * val(self.exceed_any),
            "error_bound_ppm": PPM * bound,
            "quantiles_position_um": quantiles(self.quantile_position_mm, MM2UM),
            "quantiles_phi_arcsec": quantiles(self.quantile_phi_deg, DEG2ARCSEC),
            "quantile_error_bounds_position_um": quantiles(self.quantile_position_err_mm, MM2UM),
            "quantile_error_bounds_phi_arcsec": quantiles(self.quantile_phi_err_deg, DEG2ARCSEC),
            "ppk_position": finite(float(self.ppk("position")[index])),
            "ppk_phi": None if self.exceed_phi is None else finite(float(self.ppk("phi")[index])),
            "worst_case_position_um": finite(MM2UM * val(self.worst_position_mm)),
            "worst_case_phi_arcsec": finite(DEG2ARCSEC * val(self.worst_phi_deg)),
            "rss_position_um": MM2UM * val(self.rss_position_mm),
            "rss_phi_arcsec": DEG2ARCSEC * val(self.rss_phi_deg),
            "method": self.method,
        }
        return record
