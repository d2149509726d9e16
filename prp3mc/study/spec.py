"""A study's accuracy spec: its ``[spec]`` table, the exact yield per configuration, its summary.

The table (layout in :mod:`prp3mc.study.reader`)::

    [spec]
    position_um = 100.0     # S: the position error |(dx, dy)| must stay within it, µm
    phi_arcsec = 60.0       # Z: |dphi| must stay within it, arcsec (optional)

For every configuration the study computes, without sampling,
:func:`prp3mc.exact_yield` at every pose of its Monte Carlo grid (the same
poses as the Monte Carlo percentiles, so the report compares them pose by
pose): P(position > S), P(``|dphi|`` > Z), P(either), their error bounds, the
one-sided Ppk = Phi^-1(1 - P) / 3 and the exact quantiles p99.73, p99.9937,
p99.9999; and, at the pose where P(position > S) is largest, the exceedance
curve P(position > s) over s (the report's log-axis figure).

One spec, not two: ``[montecarlo] tolerance_mm`` (older study files) is the
same position spec in mm. Without ``[spec]`` it is taken as
``position_um = 1000 * tolerance_mm``; with ``[spec]`` it may be left out
(the Monte Carlo run then counts P(position > S) against ``[spec]``), and if
both are given they must agree.

Unit sanity: a spec below 1 µm or 1 arcsec is taken with a warning naming
the unit (0.06 is more likely a spec in mm typed as µm: 60), as every entry
point takes it (:func:`prp3mc.exact_yield`, ``prp3mc yield``, allocations).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import Prp3mcWarning
from ..model.linear import linear_model
from ..montecarlo.propagation import _wilson
from ..stackup import OUTPUTS, YieldResult, exact_yield
from ..stackup.result import PPM
from ..units import DEG2ARCSEC, MM2UM, RAD2DEG, SPEC_UNITS, spec_value

__all__ = ["YieldSpec", "ExceedanceCurve", "read_spec", "run_yield", "exceedance_curve", "yield_summary",
           "CURVE_POINTS"]

_KEYS = {"position_um", "phi_arcsec"}
#: Spec values of an exceedance curve (the smallest probability it shows is the figure's,
#: :data:`prp3mc.reports.yield_plots.EXCEEDANCE_FLOOR`).
CURVE_POINTS = 20


@dataclass(frozen=True, slots=True)
class YieldSpec:
    """A validated accuracy spec of a study.

    Attributes
    ----------
    position_um : float
        S, µm.
    phi_arcsec : float or None
        Z, arcsec.
    source : str
        Where it was read: ``[spec]`` or ``[montecarlo] tolerance_mm``.
    """

    position_um: float
    phi_arcsec: float | None = None
    source: str = "[spec]"

    @property
    def position_mm(self) -> float:
        return self.position_um / MM2UM

    def record(self) -> dict:
        """``{"position_um", "phi_arcsec", "source"}`` for summary.json."""
        return {"position_um": self.position_um, "phi_arcsec": self.phi_arcsec, "source": self.source}


def _value(reader, table: dict, key: str) -> float | None:
    """``[spec] key``: a number > 0 (else refused, naming its line); below 1 of its unit taken with a warning,
    worded as :func:`prp3mc.exact_yield` and ``prp3mc allocate`` word it (one rule, one text)."""
    path, units = ("spec", key), SPEC_UNITS[f"spec_{key}"]
    value = reader.get(table, path, "number")
    if value is None:
        return None
    if not value > 0:
        reader.fail(path, f"spec.{key} must be a finite number > 0 {units[0]}, got {value!r}")
    return spec_value(f"spec_{key}", value)


def read_spec(reader, doc: dict, tolerance_mm: float | None) -> YieldSpec | None:
    """The ``[spec]`` table of a study document, reconciled with ``[montecarlo] tolerance_mm`` (None: neither)."""
    table = reader.get(doc, ("spec",), "table")
    if table is None:
        if tolerance_mm is None:
            return None
        return YieldSpec(position_um=MM2UM * tolerance_mm, source="[montecarlo] tolerance_mm")
    reader.unknown(table, _KEYS, ("spec",), "[spec]")
    position, phi = _value(reader, table, "position_um"), _value(reader, table, "phi_arcsec")
    if position is None:
        reader.fail(("spec",), "[spec] needs position_um (the position error's spec, µm); phi_arcsec is optional")
    if tolerance_mm is not None and not math.isclose(MM2UM * tolerance_mm, position, rel_tol=1e-9):
        reader.fail(("montecarlo", "tolerance_mm"), f"[montecarlo] tolerance_mm = {tolerance_mm:g} mm and [spec] "
                    f"position_um = {position:g} µm are one spec with two values: drop tolerance_mm "
                    "([spec] sets the Monte Carlo tolerance too)")
    return YieldSpec(position_um=position, phi_arcsec=phi)


@dataclass(frozen=True, slots=True)
class ExceedanceCurve:
    """P(output > s) over spec values s at one pose, exact and from the Monte Carlo samples.

    Attributes
    ----------
    output : str
        ``position`` (mm) or ``phi`` (``|δφ|``, deg).
    pose : ndarray (3,)
        ``[x_mm, y_mm, phi_deg]``.
    spec : float
        The study's spec, mm or deg.
    s : ndarray (K,)
        Spec values, mm or deg.
    exact, bound : ndarray (K,)
        Exact P(output > s) and its error bound.
    worst : float
        The exact worst case at the pose (P = 0 beyond it; NaN for unbounded laws).
    mc_s, mc_p, mc_ci : ndarray (M,), (M,), (M, 2) or None
        Monte Carlo P(output > s) at some of the ``s`` and its 95 % Wilson interval (None without Monte Carlo).
    n_samples : int
    """

    output: str
    pose: np.ndarray
    spec: float
    s: np.ndarray
    exact: np.ndarray
    bound: np.ndarray
    worst: float
    mc_s: np.ndarray | None = None
    mc_p: np.ndarray | None = None
    mc_ci: np.ndarray | None = None
    n_samples: int = 0


def run_yield(config, budget, spec: YieldSpec, grid: tuple) -> YieldResult:
    """The exact yield of one configuration at every pose of ``grid`` over its test region."""
    return exact_yield(config.geometry, budget, config.region.grid(grid), spec_position_um=spec.position_um,
                       spec_phi_arcsec=spec.phi_arcsec)


def exceedance_curve(config, budget, result: YieldResult, output: str, samples: np.ndarray | None = None,
                     points: int = CURVE_POINTS) -> ExceedanceCurve:
    """P(output > s) at the pose where the study's exceedance of ``output`` is largest, exact and Monte Carlo.

    ``samples``: the Monte Carlo run's budget draws (None: no Monte Carlo
    points). The spec values run from a quarter of the exact p99.73 up to
    the worst case (1.1 p99.9999 for unbounded laws), ``points`` of them,
    the study's spec among them.
    """
    k = int(np.argmax(result.exceedance(output).reshape(-1)))
    pose = result.poses.reshape(-1, 3)[k]
    to_um = MM2UM if output == "position" else DEG2ARCSEC
    if output == "position":
        spec = result.spec_position_mm
        worst = float(result.worst_position_mm.reshape(-1)[k])
        q = result.quantile_position_mm.reshape(-1, len(result.levels))[k]
    else:
        spec = result.spec_phi_deg
        worst = float(result.worst_phi_deg.reshape(-1)[k])
        q = result.quantile_phi_deg.reshape(-1, len(result.levels))[k]
    top = worst if np.isfinite(worst) else float(q[-1]) * 1.1
    s = np.unique(np.append(np.linspace(0.25 * float(q[0]), top, points), spec))
    s = s[s > 0]
    exact, bound = np.empty_like(s), np.empty_like(s)
    for j, v in enumerate(s):          # one spec value per call: exact_yield takes a scalar spec
        kw = ({"spec_position_um": to_um * v} if output == "position" else
              {"spec_position_um": MM2UM * result.spec_position_mm, "spec_phi_arcsec": to_um * v})
        with warnings.catch_warnings():  # of the joint channel, not drawn; this channel's bound is kept and shown
            warnings.simplefilter("ignore", Prp3mcWarning)
            r = exact_yield(config.geometry, budget, pose, quantiles=False, joint=False, **kw)
        exact[j], bound[j] = float(r.exceedance(output)), float(r.bound(output))
    curve = dict(output=output, pose=pose, spec=float(spec), s=s, exact=exact, bound=bound, worst=worst)
    if samples is not None:
        err = linear_model(config.geometry, budget, pose[None]).evaluate(samples)[0]   # (n, 3) mm, mm, rad
        values = np.hypot(err[:, 0], err[:, 1]) if output == "position" else np.abs(err[:, 2]) * RAD2DEG
        mc_s = s[:: max(1, len(s) // 8)]
        counts = (values[None, :] > mc_s[:, None]).sum(axis=1)
        n = len(values)
        curve.update(mc_s=mc_s, mc_p=counts / n, mc_ci=_wilson(counts, n), n_samples=n)
    return ExceedanceCurve(**curve)


def _exact(values: np.ndarray, scale: float = 1.0) -> dict:
    """``{"min", "max", "mean"}`` over a grid of an exact statistic (no standard error), times ``scale``
    (also the worst case's in :mod:`prp3mc.study.summary`)."""
    v = scale * np.asarray(values, dtype=float)
    return {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean())}


def _ppk_min(result: YieldResult, output: str) -> float | None:
    """The least Ppk over the grid (at the largest exceedance); None (JSON null) when it is infinite (P = 0)."""
    v = float(result.ppk(output).min())
    return v if math.isfinite(v) else None


def yield_summary(result: YieldResult, spec: YieldSpec, grid: tuple) -> dict:
    """The ``yield`` entry of a configuration in summary.json (layout in :mod:`prp3mc.study.summary`)."""
    outputs = result.outputs
    out = {"spec": spec.record(), "grid": list(grid)}
    for o in OUTPUTS:
        if o in outputs:
            out[f"exceed_{o}_ppm"] = _exact(result.exceedance(o), PPM)
            out[f"exceed_{o}_pct"] = _exact(result.exceedance(o), 100.0)
        else:
            out[f"exceed_{o}_ppm"] = out[f"exceed_{o}_pct"] = None
    out["ppk_min"] = {o: (_ppk_min(result, o) if o in outputs else None) for o in OUTPUTS}
    out["error_bound_ppm"] = float(PPM * result.error_bound.max())
    out["error_bounds_ppm"] = {o: (float(PPM * result.bound(o).max()) if o in outputs else None) for o in OUTPUTS}
    levels = [f"p{lv:g}" for lv in result.levels]
    out["quantiles_position_um"] = {k: _exact(result.quantile_position_mm[..., q], MM2UM) for q, k in enumerate(levels)}
    out["quantile_error_bounds_position_um"] = {k: float(MM2UM * result.quantile_position_err_mm[..., q].max())
                                                for q, k in enumerate(levels)}
    out["quantiles_phi_arcsec"] = {k: _exact(result.quantile_phi_deg[..., q], DEG2ARCSEC)
                                   for q, k in enumerate(levels)}
    out["quantile_error_bounds_phi_arcsec"] = {k: float(DEG2ARCSEC * result.quantile_phi_err_deg[..., q].max())
                                               for q, k in enumerate(levels)}
    out["rss_position_um"] = _exact(result.rss_position_mm, MM2UM)
    out["region"] = result.region_summary()
    out["method"] = result.method
    return out
