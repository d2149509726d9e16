"""``summary.json``: the summary statistics of a study, for regression checks.

Layout (µm and arcsec)::

    {"study": "paper_reproduction",
     "configurations": {
       "u-shape": {
         "worst_case_position_um": {"min": 116.9, "max": 194.6, "mean": 150.3},
         "worst_case_phi_arcsec": {"min": ..., "max": ..., "mean": ...},
         "montecarlo": {
           "position_um": {"p99.73": {"min": {"value": 120.1, "se": 0.4}, "max": {...}, "mean": {...}}, ...,
                           "mean": {"min": ..., "max": ..., "mean": ...}},
           "phi_arcsec": {"p99.73": {...}, ...},
           "std": {"x_um": {...}, "y_um": {...}, "phi_arcsec": {...}},
           "exceed": {"tolerance_mm": 0.1, "probability": {"min": ..., "max": ..., "mean": ...},
                      # when it stands in for the exact yield (correlated inputs not all normal, or
                      # NoExactYieldError: no density, too many classes or terms) with a phi spec:
                      "tolerance_phi_arcsec": 60.0, "phi_probability": {...}, "any_probability": {...}}},
         "sobol": {"position": {"theta_1": {"kind": "input", "S1": {"value": ..., "se": ...},
                                            "ST": {...}, "worst_case_share": 0.31}, ...}, ...}},
                                            # worst_case_share null where undefined (rho_i, zeta_i alone);
                                            # S1, ST null, with a "reason", for a known shift (kind "shift")
                                            # or a constant input
         "allocation": {"cost": 26.0, "choice": {"rho_1": "CN", ...}, "worst_case_position_um": 77.6,
                        "worst_case_phi_arcsec": 88.2, "feasible": true,
                        "spec": {"position_um": 80.0, "phi_arcsec": 120.0, "percentile": null},
                        "binding": "position", "binding_poses": [{"x_mm": ..., "y_mm": ..., "phi_deg": ...}],
                        "front": [{"cost": 12.0, "worst_case_position_um": ..., "worst_case_phi_arcsec": ...}, ...]}},
                                            # with [allocation]; layout in prp3mc.study.allocation
         "yield": {"spec": {"position_um": 100.0, "phi_arcsec": null, "source": "[spec]"},
                   "grid": [21, 21],                      # the Monte Carlo grid's poses
                   "exceed_position_ppm": {"min": ..., "max": ..., "mean": ...}, "exceed_position_pct": {...},
                   "exceed_phi_ppm": {...} or null, "exceed_phi_pct": ..., "exceed_any_ppm": ..., "exceed_any_pct": ...,
                   "ppk_min": {"position": 1.02, "phi": null, "any": ...},   # null: no spec, or P = 0 (infinite)
                   "error_bound_ppm": 0.001,              # the largest bound of every exceedance at every pose
                   "error_bounds_ppm": {"position": ..., "phi": ..., "any": ...},
                   "quantiles_position_um": {"p99.73": {"min", "max", "mean"}, "p99.9937": ..., "p99.9999": ...},
                   "quantile_error_bounds_position_um": {"p99.73": ..., ...},     # largest over the grid
                   "quantiles_phi_arcsec": {...}, "quantile_error_bounds_phi_arcsec": {...},
                   "rss_position_um": {"min", "max", "mean"},
                   "region": {"max_exceed_position_ppm": ..., "mean_exceed_position_ppm": ...,
                              "area_fraction_above_1ppm": ..., "argmax_pose": [x, y, phi]},   # as prp3mc yield
                   "method": "..."}},             # with a spec ([spec] or [montecarlo] tolerance_mm);
                                                  # layout in prp3mc.study.spec
       "delta-shape": {...}},
     "metadata": {"prp3mc_version": ..., "seed": ..., "montecarlo_samples": ..., "wall_time_s": ...},
     "inputs": {"study": {"name": "quick", "file": "/abs/quick.toml", "sha256": "..."},
                "budget": {"name": "paper", "preset": "paper"},     # or "file" and "sha256"; with
                                   # [effects]: "effects" {name: table} and "fitted_on" (geometry name)
                "configurations": {"u-shape": {"geometry": {"name": "u-shape", "preset": "u-shape"},
                                               "region": {"x_mm": [-40, 40], "y_mm": [60, 140], "phi_deg": 0}}},
                "seed": 7, "montecarlo_seed": ..., "sobol_seed": ..., "worstcase_grid": [41, 41],
                "montecarlo_samples": 32768, ...},
     "versions": {"prp3mc": ..., "python": ..., "numpy": ..., "scipy": ..., "pandas": ..., "SALib": ...},
     "warnings": ["budget 'b': no law for theta_3 (other legs have one): taken as exact; ..."],
                                            # only when there are any: the budget's, or those a command gave
     "correlation": {                       # only for a budget with a [correlation] table (SPEC §10)
        "table": {"bearings": 0.8, "theta_1,theta_2": 0.5},     # as written (also in inputs.budget)
        "copula": "Gaussian",
        "pairs": [{"inputs": ["rho_1", "rho_2"], "spearman": 0.8, "latent": 0.813,
                   "realised": {"value": 0.799, "se": 0.002}}, ...],   # every correlated pair, groups expanded
        "realised_from": {"samples": 32768},    # the Monte Carlo draws of the budget (inputs.montecarlo_seed)
        "analyses": {"montecarlo": {"respects": true, "how": "..."}, "shapley": {...},
                     "sobol": {"respects": false, "how": "not defined: ..."},
                     "worst_case": {"respects": false, "how": "a box: ..."},
                     "yield": {"respects": true, "how": "exact: ..."}, ...}}}   # with a spec: the exact
                                            # series, or the Monte Carlo fallback (montecarlo.exceed)

A study with a ``[sweep]`` table (SPEC §8) names its expanded configurations
``base.k``; each entry also carries ``"parameters": {key: value}`` with the
sweep keys as written in the file, and a top-level ``"sweep"`` lists what did
not run::

     "sweep": {"parameters": {"leg.3.a_mm": [200, 220, 240], ...}, "configurations": 9,
               "infeasible": [{"name": "u-shape.7", "parameters": {...}, "reason": "..."}],
               "failed": [...]}

The summary is the same whether the study ran serially or on a Dask cluster
(only ``metadata.wall_time_s`` and ``metadata.timings_s`` differ).

A plain number is **exact** (the worst case is a deterministic function of
geometry, budget and grid); a ``{"value", "se"}`` pair is a **statistic** with
its standard error. ``min``/``max``/``mean`` are taken over the analysis'
grid of the configuration's test region. Standard errors: a percentile's
from its distribution-free 95 % interval (half-width / 1.96), at the pose
that gives the min or max; a mean over the grid carries the mean of the
pose-wise standard errors (an upper bound under the common random numbers
all poses share); a Sobol index's (and a Shapley effect's) is its half-width over the Student t
quantile of its replicates (``conf / t(0.95, R - 1)``, the standard error of the mean of R replicates).
A correlated budget has no Sobol indices (S1 and ST null, with the ``reason``); its Shapley effects ``Sh``
share the variance. Its ``correlation`` entry records the table, every pair it correlates with the rank
correlation asked for and the one realised in the Monte Carlo draws (standard error from Fieller's
var(atanh rho_S) = 1.06 / (n - 3)), and which analyses of the study respected it.
A Sobol entry's ``worst_case_share`` is taken at the grid pose where the
worst case is largest (the report's figures use the mean over the grid, as
for the indices). ``inputs`` and ``versions`` say what the run was made
from: the study file, the budget and each geometry (preset name, or file
and sha256), seeds and sizes, and the package versions.
:func:`prp3mc.testing.assert_summary_close` compares two summaries and
skips ``metadata``, ``inputs`` and ``versions``.
"""

from __future__ import annotations

import tomllib
import warnings
from pathlib import Path

import numpy as np

from ..errors import Prp3mcError, Prp3mcWarning
from ..kinematics.geometry import Geometry
from ..provenance import file_record, spec_record, versions
from ..model.budget import Budget
from ..units import DEG2ARCSEC, MM2UM, t_value
from ..sobol.indices import DEPENDENT_NOTE
from ..stackup.gaussian import exact_refusal
from ..worstcase.envelope import CORRELATION_NOTE
from .allocation import allocation_summary
from .spec import _exact, yield_summary
from .results import ConfigurationResult, StudyResult, over_grid, pct_se

__all__ = ["build_summary", "study_inputs", "correlation_summary"]


def _undefined(name: str, kind: str, constant: set, correlated: bool) -> str:
    """Why a Sobol index is undefined (it is NaN in the result, null in summary.json)."""
    if kind == "shift":
        return ("undefined: a known shift (an offset, lead scale or cyclic screw error of the budget's effects) has "
                "no variance to share")
    if name in constant:
        return "undefined: a constant input (zero-width law) has no variance to share"
    if correlated:
        return f"undefined: {DEPENDENT_NOTE}"
    return "undefined: the output does not vary over the budget"


def _stat(value, se) -> dict:
    return {"value": float(value), "se": float(se)}


def _over_grid(values: np.ndarray, se: np.ndarray) -> dict:
    """min, max and mean over a grid of a statistic with pose-wise standard errors."""
    return {k: _stat(v, s) for k, (v, s) in over_grid(values, se).items()}


def _exact_or_none(value) -> float | None:
    """An exact number, or None (JSON null) where it is undefined (NaN)."""
    return None if np.isnan(value) else float(value)


def _montecarlo(c: ConfigurationResult) -> dict:
    mc = c.montecarlo
    pos = {f"p{p:g}": _over_grid(MM2UM * mc.position_pct[..., q], MM2UM * pct_se(mc.position_pct_ci[..., q, :]))
           for q, p in enumerate(mc.percentiles)}
    pos["mean"] = _over_grid(MM2UM * mc.position_mean, MM2UM * mc.position_mean_se)
    phi = {f"p{p:g}": _over_grid(DEG2ARCSEC * mc.phi_pct[..., q], DEG2ARCSEC * pct_se(mc.phi_pct_ci[..., q, :]))
           for q, p in enumerate(mc.percentiles)}
    std = {key: _over_grid(f * mc.std[..., o], f * mc.std_se[..., o])
           for o, (key, f) in enumerate((("x_um", MM2UM), ("y_um", MM2UM), ("phi_arcsec", DEG2ARCSEC)))}
    out = {"position_um": pos, "phi_arcsec": phi, "std": std}
    if mc.exceed_prob is not None:
        out["exceed"] = {"tolerance_mm": float(mc.tolerance_mm),
                         "probability": _over_grid(mc.exceed_prob, pct_se(mc.exceed_ci))}
        if mc.exceed_phi_prob is not None:        # the yield's Monte Carlo fallback: |dphi| and either too
            out["exceed"] |= {"tolerance_phi_arcsec": float(DEG2ARCSEC * mc.tolerance_phi_deg),
                              "phi_probability": _over_grid(mc.exceed_phi_prob, pct_se(mc.exceed_phi_ci)),
                              "any_probability": _over_grid(mc.exceed_any_prob, pct_se(mc.exceed_any_ci))}
    return out


def _sobol(c: ConfigurationResult) -> dict:
    """Indices of every factor and group; S1, ST (and Sh) null, with the ``reason``, where undefined (JSON has no NaN)."""
    out = {}
    r = c.sobol
    constant = set(getattr(r, "constant", ()))
    t = t_value(r.conf_level, r.replicates - 1)
    stats = r.statistics
    for output, frame in c.ranking.items():
        entries = {}
        for row in frame.itertuples(index=False):
            entry = {"kind": row.kind, **{k: _stat(getattr(row, k), getattr(row, f"{k}_conf") / t) for k in stats},
                     "worst_case_share": _exact_or_none(row.worst_case_share)}
            values = [getattr(row, k) for k in stats] + [getattr(row, f"{k}_conf") for k in stats]
            if not np.isfinite(values).all():
                entry.update({k: None for k in stats if not np.isfinite([getattr(row, k), getattr(row, f"{k}_conf")]).all()},
                             reason=_undefined(row.name, row.kind, constant, r.correlated))
            entries[row.name] = entry
        out[output] = entries
    return out


def _file_specs(source: str) -> tuple[Path, list[str], list[str]]:
    """The study file's folder and the budget and geometry specs it names (empty if it cannot be read)."""
    path = Path(source)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return path.parent, [], []
    configs = doc.get("configuration", [])
    geometries = [c["geometry"] for c in configs if isinstance(c, dict) and isinstance(c.get("geometry"), str)]
    budget = doc.get("budget", "paper")
    return path.parent, [budget] if isinstance(budget, str) else [], geometries


def _record(used, specs: list[str], base: Path, loader) -> dict:
    """How ``used`` (a Budget or Geometry) was named in the study file: preset, or file and sha256.

    The first spec of the file that loads to ``used`` is recorded; a budget
    or geometry that none gives (replaced in code, or varied by a sweep) is
    recorded by name only.
    """
    for spec in specs:
        target = base / spec if spec.endswith(".toml") else spec
        try:
            with warnings.catch_warnings():  # given once already, when the study was read
                warnings.simplefilter("ignore", Prp3mcWarning)
                if loader(target) == used:
                    return spec_record(target, used)
        except Prp3mcError:
            continue
    return {"name": used.name, "note": "not as the study file names it (replaced in code, or varied)"}


def study_inputs(result: StudyResult) -> dict:
    """What a study run was made from (the ``inputs`` of ``summary.json``; layout in the module docstring)."""
    study = result.study
    base, budgets, geometries = _file_specs(study.source)
    record = {"name": study.name}
    if Path(study.source).is_file():
        record.update(file_record(study.source))
    configs = {}
    for c in study.configurations:
        region = c.region
        configs[c.name] = {"geometry": _record(c.geometry, geometries, base, Geometry.load),
                           "region": {"x_mm": [float(v) for v in region.x_mm],
                                      "y_mm": [float(v) for v in region.y_mm], "phi_deg": float(region.phi_deg)}}
    budget = _record(study.budget, budgets, base, Budget.load) | study.budget.effects_record()
    if study.budget.missing_inputs:
        budget["missing_inputs"] = list(study.budget.missing_inputs)
    if study.budget.correlated:
        budget["correlation"] = dict(study.budget.correlation)
    out = {"study": record, "budget": budget,
           "configurations": configs, "seed": result.seed, "montecarlo_seed": result.montecarlo_seed,
           "sobol_seed": result.sobol_seed, **study.sizes()}
    if getattr(study, "allocation", None) is not None:
        source = study.allocation.classes_source
        out["allocation_classes"] = spec_record(base / source if source.endswith(".toml") else source,
                                                study.allocation.classes)
        if getattr(result, "allocation_seed", None) is not None:
            out["allocation_seed"] = result.allocation_seed
    return out


#: Draws of the budget the realised rank correlations are measured on when the study runs no Monte Carlo.
REALISED_SAMPLES = 1 << 15


def _analyses_under_correlation(study) -> dict:
    """Which analyses of ``study`` respected its budget's correlation, and how (``respects``, ``how``)."""
    out = {"worst_case": {"respects": False, "how": "unchanged, a box. " + CORRELATION_NOTE}}
    if "montecarlo" in study.outputs:
        out["montecarlo"] = {"respects": True, "how": "each draw of the correlated inputs passes through the "
                             "Gaussian copula; every percentile, mean and probability is of the dependent inputs"}
    if "sobol" in study.outputs:
        out["shapley"] = {"respects": True, "how": "Shapley effects Sh are defined for dependent inputs: each "
                          "input's share of the output variance averaged over the orders of the inputs, the "
                          "conditional draws taken from the copula"}
        out["sobol"] = {"respects": False, "how": f"not defined: {DEPENDENT_NOTE}"}
    if study.spec is not None and "yield" in study.outputs:
        refusal = exact_refusal(study.budget)
        if refusal is None:
            out["yield"] = {"respects": True, "how": "exact: the correlated inputs are all normal, hence jointly "
                            "normal, and enter the exact series as independent normal terms with the same joint "
                            "law (each input's own part, and the rest of their covariance along at most three "
                            "principal directions of the pose error); the error bound holds as for an independent "
                            "budget"}
        else:
            out["yield"] = {"respects": "montecarlo" in study.outputs,
                            "how": f"no exact series: {refusal}; " + (
                                "the Monte Carlo run (with the copula) gives P(> spec) of the position, |δφ| and "
                                "either with Wilson 95 % intervals (montecarlo.exceed)" if "montecarlo" in
                                study.outputs else "not computed (the study runs no Monte Carlo)")}
    if getattr(study, "allocation", None) is not None:
        out["allocation"] = {"respects": False, "how": "not applied: the allocation's budget is the classes "
                             "menu's laws, taken independent"}
    return out


def correlation_summary(result: StudyResult) -> dict | None:
    """The ``correlation`` entry of ``summary.json`` (layout in the module docstring); None for an independent budget.

    The realised rank correlations are those of the Monte Carlo draws
    (``budget.sample(montecarlo_samples, montecarlo_seed)``; without a
    Monte Carlo, :data:`REALISED_SAMPLES` draws of that seed). The seed is
    in ``inputs`` (``montecarlo_seed``), so that two runs' summaries compare.
    """
    from scipy import stats
    budget, study = result.study.budget, result.study
    cop = budget.copula
    if cop is None:
        return None
    n = study.mc_samples if "montecarlo" in study.outputs else REALISED_SAMPLES
    X = budget.sample(n, result.montecarlo_seed)[:, list(cop.index)]
    realised = np.corrcoef(stats.rankdata(X, axis=0), rowvar=False)    # Spearman's, a matrix even for two inputs
    z_se = float(np.sqrt(1.06 / (n - 3)))
    pairs = []
    for a in range(len(cop.names)):
        for b in range(a):
            if cop.spearman[a, b] != 0.0:
                r = float(realised[a, b])
                pairs.append({"inputs": [cop.names[b], cop.names[a]], "spearman": float(cop.spearman[a, b]),
                              "latent": float(cop.latent[a, b]),
                              "realised": {"value": r, "se": (1.0 - r * r) * z_se}})
    return {"table": dict(budget.correlation), "copula": "Gaussian", "pairs": pairs,
            "realised_from": {"samples": int(n)},
            "analyses": _analyses_under_correlation(study)}


def build_summary(result: StudyResult) -> dict:
    """The summary of a study run as a JSON-ready dict (layout in the module docstring); also
    :meth:`StudyResult.to_dict() <prp3mc.study.results.StudyResult.to_dict>`.

    A plain dict, not a result object: it is the ``summary.json`` document itself, which is
    written, compared with :func:`prp3mc.testing.assert_summary_close` and read back as is;
    the result it summarises is the :class:`~prp3mc.study.results.StudyResult`.
    """
    configs = {}
    for c in result.configurations:
        wc = c.worst_case
        doc = {"worst_case_position_um": _exact(MM2UM * wc.position_mm),
               "worst_case_phi_arcsec": _exact(DEG2ARCSEC * wc.phi_deg)}
        if c.montecarlo is not None:
            doc["montecarlo"] = _montecarlo(c)
        if c.sobol is not None:
            doc["sobol"] = _sobol(c)
        if c.allocation is not None:
            doc["allocation"] = allocation_summary(c.allocation, c.allocation_front)
        if c.yield_ is not None:
            doc["yield"] = yield_summary(c.yield_, result.study.spec, result.study.mc_grid)
        if result.study.sweep:
            doc["parameters"] = dict(c.configuration.parameters)
        configs[c.name] = doc
    out = {"study": result.study.name, "configurations": configs}
    if result.study.sweep:
        out["sweep"] = {"parameters": {k: list(v) for k, v in result.study.sweep},
                        "configurations": len(result.configurations) + len(result.skipped),
                        **{kind: [s.to_dict() for s in result.skipped if s.kind == kind]
                           for kind in ("infeasible", "failed")}}
    notes = result.study.budget.warnings
    correlation = correlation_summary(result)
    return out | {"metadata": result.metadata(), "inputs": study_inputs(result), "versions": versions(),
                  **({"warnings": list(notes)} if notes else {}),
                  **({"correlation": correlation} if correlation is not None else {})}
