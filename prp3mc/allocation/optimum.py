"""Tolerance allocation: the least-cost classes that keep the pose error within a spec over a region.

:func:`allocate` chooses one class per input (every leg independently) from a
:class:`~prp3mc.allocation.classes.ClassMenu` so that the exact
worst case of the linear model stays within a position and/or orientation
spec at every pose of a region, at the least total cost: proven optimal by
branch and bound on the monotone envelope
(:mod:`~prp3mc.allocation.search`). With ``spec_percentile`` the
position spec bounds that percentile of the position error instead: the
exact distribution of the linear model decides whether a choice meets it
(Monte Carlo with the budget's copula when the budget correlates its
inputs), the closed-form normal screen proposes the choices, small menus are
searched to a proof (:mod:`~prp3mc.allocation.percentile`), and Monte Carlo
confirms the choice with a confidence interval at every pose.
:func:`allocation_front` sweeps the cost-accuracy Pareto front.

A budget's systematic effects (its ``[effects]`` table: fitted offsets,
lead scales, backlash, thermal expansion) are properties of the machine, not
classes to buy: given ``budget=``, they stay fixed in every candidate, every
bound, the Monte Carlo confirmation and the reported worst case. Its
``[correlation]`` table goes with every candidate too: a percentile spec
is then decided by Monte Carlo; the worst case stays the box's (correlation
leaves every corner possible).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..progress import Progress
from .._result import freeze, pose_columns, short_repr
from .._rng import child_seed, resolve_rng
from .._version import __version__
from ..errors import AllocationError
from ..kinematics.geometry import Geometry, Region
from ..kinematics.chain import as_poses
from ..stackup.result import PPM
from ..units import DEG2ARCSEC, MM2UM, spec_value
from .classes import ClassMenu
from .percentile import METHODS, PercentileCheck, percentile_least_cost
from .search import Problem, Search, least_cost
from ..model.budget import Budget
from ..montecarlo.propagation import ci_samples, monte_carlo
from ..worstcase.envelope import worst_case

__all__ = ["AllocationResult", "allocate", "allocation_front", "front_records"]

@dataclass(frozen=True, slots=True)
class AllocationResult:
    """The chosen classes, their cost and how they meet the spec.

    Attributes
    ----------
    choice : dict of str to str
        Input (``rho_1``, ``theta_2``, ...) to its class name.
    cost : float
        Total cost (the user's unit).
    feasible : bool
        Whether the choice meets the spec (for a statistical spec: as
        :class:`~prp3mc.allocation.percentile.PercentileCheck` decides it). When False, ``choice`` is the one
        closest to the spec (smallest largest ratio of value to spec).
    spec : dict
        ``position_mm``, ``phi_deg`` (None when not given), ``percentile``
        (None: the position spec bounds the worst case).
    poses : ndarray (N, 3)
    position_mm, phi_deg : ndarray (N,)
        Exact worst case of the chosen classes at every pose.
    binding : str
        The constraint with the least slack: ``position``, ``phi`` or ``percentile``.
    binding_poses : ndarray (m, 3)
        Where it binds: the poses within ``binding_rtol`` of the region maximum
        (worst case), or the pose where the percentile's CI upper bound is largest.
    statistical : dict or None
        For a statistical spec: ``percentile``, ``method`` (``exact`` or
        ``monte_carlo`` for a correlated budget, see
        :data:`~prp3mc.allocation.percentile.METHODS`), ``exceedance`` (exact:
        the largest exceedance of S plus its error bound over the poses),
        ``screen_mm`` (the normal screen, region max), ``percentile_mm``,
        ``ci_high_mm`` (Monte Carlo estimate and its 95 % upper bound at the
        binding pose, region max of the upper bound), ``n_samples``, ``seed``,
        ``checks`` (choices decided), ``proven`` (every cheaper choice was
        decided, see :func:`~prp3mc.allocation.percentile.percentile_least_cost`),
        ``confirmed`` (by Monte Carlo).
    nodes : int
        Candidates the branch and bound evaluated (of ``n_choices``).
    n_choices : int
        Size of the whole choice space (the product of the menus).
    menu : ClassMenu
    geometry : Geometry
    seed : int or None
    fixed : Budget or None
        The budget whose ``[effects]`` stayed fixed (its inputs played no part).
    """

    choice: dict
    cost: float
    feasible: bool
    spec: dict
    poses: np.ndarray
    position_mm: np.ndarray
    phi_deg: np.ndarray
    binding: str
    binding_poses: np.ndarray
    statistical: dict | None
    nodes: int
    n_choices: int
    menu: ClassMenu
    geometry: Geometry
    seed: int | None = None
    fixed: Budget | None = None
    version: str = __version__
    wall_time_s: float = field(default=float("nan"), compare=False)

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "cost", "feasible", "binding", "nodes", "n_choices")

    @property
    def worst_case_position_mm(self) -> float:
        return float(self.position_mm.max())

    @property
    def worst_case_phi_deg(self) -> float:
        return float(self.phi_deg.max())

    def budget(self) -> Budget:
        """The error budget of the chosen classes (with the fixed effects, if any)."""
        return self.menu.budget(self.choice, self.fixed)

    def choice_frame(self) -> pd.DataFrame:
        """One row per input: input, class, cost, law, lo, hi, unit, source."""
        rows = []
        for name, cls_name in self.choice.items():
            c = next(c for c in self.menu.classes_of(name) if c.name == cls_name)
            rows.append({"input": name, "class": cls_name, "cost": c.cost, "law": c.law.kind,
                         "lo": c.law.support[0], "hi": c.law.support[1],
                         "unit": "mm" if name.split("_")[0] in ("a", "b", "c", "e", "rho") else "deg",
                         "source": c.source})
        return pd.DataFrame(rows)

    def to_frame(self) -> pd.DataFrame:
        """Tidy per-pose worst case of the choice: x_mm, y_mm, phi_deg, output, statistic, value, unit."""
        frames = [pd.DataFrame({**pose_columns(self.poses), "output": out, "statistic": "worst_case",
                                "value": values, "unit": unit})
                  for out, values, unit in (("position", self.position_mm, "mm"), ("phi", self.phi_deg, "deg"))]
        return pd.concat(frames, ignore_index=True)

    def to_dict(self) -> dict:
        """The ``prp3mc allocate --json`` object (µm, arcsec) with the binding poses, the spec and the search."""
        spec = {"position_um": _scaled(self.spec["position_mm"], MM2UM),
                "phi_arcsec": _scaled(self.spec["phi_deg"], DEG2ARCSEC), "percentile": self.spec["percentile"]}
        doc = {"cost": self.cost, "choice": dict(self.choice),
               "worst_case_position_um": MM2UM * self.worst_case_position_mm,
               "worst_case_phi_arcsec": DEG2ARCSEC * self.worst_case_phi_deg,
               "feasible": self.feasible, "spec": spec, "binding": self.binding,
               "binding_poses": [dict(zip(("x_mm", "y_mm", "phi_deg"), map(float, p))) for p in self.binding_poses],
               "search": {"nodes": self.nodes, "n_choices": self.n_choices, "wall_time_s": self.wall_time_s}}
        if self.fixed is not None:
            doc["fixed_effects"] = {k: {"value": e.value, "unit": e.unit} for k, e in self.fixed.effects.items()}
        if self.statistical is not None:
            st = self.statistical
            doc["statistical"] = {
                "percentile": st["percentile"], "screen_um": MM2UM * st["screen_mm"],
                "percentile_um": MM2UM * st["percentile_mm"], "ci95_high_um": MM2UM * st["ci_high_mm"],
                "method": METHODS[st["method"]],
                "exceedance_ppm": None if st["exceedance"] is None else PPM * st["exceedance"],
                "screen": "normal approximation |mu| + sqrt(lambda_max chi2_2(q)), capped by the worst case: "
                          "proposes choices, decides none",
                "n_samples": st["n_samples"], "seed": st["seed"], "checks": st["checks"], "proven": st["proven"],
                "confirmed": st["confirmed"]}
        return doc


def _scaled(value, factor):
    return None if value is None else factor * value


def region_poses(region, grid: int = 41, phi_deg: float | None = None) -> np.ndarray:
    """Flat poses (N, 3) of a Region or preset region name on a ``grid`` x ``grid`` grid, or of a pose array."""
    if isinstance(region, str):
        region = Region.from_preset(region)
    if isinstance(region, Region):
        if not (isinstance(grid, (int, np.integer)) and grid >= 2):
            raise AllocationError(f"grid must be an integer >= 2 (a 1 x 1 grid is the region's corner, not the "
                                  f"region), got {grid!r}")
        if phi_deg is not None:
            region = Region(region.x_mm, region.y_mm, phi_deg)
        return region.grid(int(grid)).reshape(-1, 3)
    return as_poses(region).reshape(-1, 3)


def _spec_limits(spec_position_um, spec_phi_arcsec, spec_percentile) -> dict:
    for name, value in (("spec_position_um", spec_position_um), ("spec_phi_arcsec", spec_phi_arcsec)):
        if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise AllocationError(f"{name} must be a finite number > 0, got {value!r}")
    if spec_position_um is None and spec_phi_arcsec is None:
        raise AllocationError("give a position spec (µm), an orientation spec (arcsec) or both")
    for name, value in (("spec_position_um", spec_position_um), ("spec_phi_arcsec", spec_phi_arcsec)):
        if value is not None:     # below 1: legal, but far more often a value in the larger unit (a warning)
            spec_value(name, value)
    if spec_percentile is not None:
        if spec_position_um is None:
            raise AllocationError("a percentile spec bounds the position error: give spec_position_um too")
        if not (isinstance(spec_percentile, (int, float)) and 50 <= spec_percentile < 100):
            hint = " (a percent: 99.73, not 0.9973)" if isinstance(spec_percentile, (int, float)) \
                and 0 < spec_percentile < 1 else ""
            raise AllocationError(f"spec_percentile must lie in [50, 100){hint}, got {spec_percentile!r}")
    key = "position" if spec_percentile is None else "screen"
    return {key: _scaled(spec_position_um, 1 / MM2UM), "phi": _scaled(spec_phi_arcsec, 1 / DEG2ARCSEC)}


def _choice(problem: Problem, idx) -> dict:
    return {name: problem.class_name(j, int(m)) for j, (name, m) in enumerate(zip(problem.inputs, idx))}


def _cost(problem: Problem, idx) -> float:
    return float(problem.cost[np.arange(len(idx)), idx].sum())


def allocate(geometry, classes, region, *, spec_position_um: float | None = None,
             spec_phi_arcsec: float | None = None, spec_percentile: float | None = None,
             grid: int = 41, phi_deg: float | None = None, k_sigma: float | None = None,
             n_samples: int = 20_000, rng: "None | int | np.random.Generator" = None,
             binding_rtol: float = 1e-3, budget=None) -> AllocationResult:
    """The least-cost class of every input that keeps the pose error within the spec over a region.

    Parameters
    ----------
    geometry : Geometry or str
        A Geometry, preset name or TOML path.
    classes : ClassMenu or str
        The menu: a ClassMenu, a bundled preset name (``example``) or a classes TOML path.
    region : Region, str or array_like (..., 3)
        A Region or preset region name (gridded ``grid`` x ``grid`` at
        ``phi_deg``, default the region's own), or the poses themselves.
    spec_position_um : float, optional
        Bound on the exact worst-case position error (µm) at every pose, or,
        with ``spec_percentile``, on that percentile of the position error.
    spec_phi_arcsec : float, optional
        Bound on the exact worst-case ``|dphi|`` (arcsec) at every pose.
    spec_percentile : float, optional
        Percentile (e.g. 99.73) of the position error the position spec bounds.
    k_sigma : float, optional
        Bound unbounded laws (normal) as mean ± k·sd for the worst case.
    n_samples : int
        Monte Carlo samples confirming a statistical spec: at least
        :func:`~prp3mc.montecarlo.propagation.ci_samples` of its percentile (1419 for p99.73).
    rng : None, int or numpy.random.Generator
        Randomness of the Monte Carlo confirmation (SPEC 7); its seed is recorded.
    binding_rtol : float
        Poses within this relative distance of the region maximum are binding.
    budget : Budget or str, optional
        A budget (or preset name or TOML path) whose ``[effects]`` stay fixed
        in every bound and check and whose ``[correlation]`` table every
        candidate takes (its inputs' laws play no part: the classes choose
        them). A budget fitted on another geometry is refused.

    Returns
    -------
    AllocationResult

    Examples
    --------
    >>> from prp3mc import allocate
    >>> r = allocate("u-shape", "example", "u-shape", spec_position_um=60.0, grid=11)
    >>> r.feasible, r.cost, r.choice["rho_1"]
    (True, 36.0, 'CN')
    """
    t0 = time.perf_counter()
    limits = _spec_limits(spec_position_um, spec_phi_arcsec, spec_percentile)
    if spec_percentile is not None and n_samples < (need := ci_samples(spec_percentile)):
        raise AllocationError(f"confirming p{spec_percentile:.10g} needs at least {need} samples (the upper end of "
                              f"its 95 % interval must lie below the sample's maximum), got {n_samples}")
    geometry, menu, fixed = Geometry.load(geometry), ClassMenu.load(classes), _fixed(budget)
    poses = region_poses(region, grid, phi_deg)
    problem = Problem(geometry, menu, poses, k_sigma=k_sigma, percentile=spec_percentile, fixed=fixed)
    statistical, seed = None, None
    if spec_percentile is None:
        idx, nodes = least_cost(problem, limits)
    else:
        seed, _ = resolve_rng(rng)
        check = PercentileCheck(geometry, problem, limits["screen"], spec_percentile, n_samples, seed)
        idx, nodes, proven = percentile_least_cost(problem, {"phi": limits["phi"]}, check)
    feasible = idx is not None
    if idx is None:
        nearest = Search(problem, limits)
        idx = nearest.closest()
        nodes += nearest.nodes
    if spec_percentile is not None:
        statistical = _confirm(geometry, problem, check, idx, feasible and proven)
    choice = _choice(problem, idx)
    wc = worst_case(geometry, problem.budget(choice), poses, k_sigma=k_sigma)
    values = {"position": wc.position_mm, "phi": wc.phi_deg}
    ratios = {q: float(values[q].max()) / limits[q] for q in ("position", "phi") if limits.get(q)}
    if statistical is not None:
        ratios["percentile"] = statistical["ci_high_mm"] / limits["screen"]
    binding = max(ratios, key=ratios.get)
    if binding == "percentile" and statistical is not None:
        binding_poses = statistical.pop("pose")[None]
    else:
        v = values["position" if binding == "percentile" else binding]
        binding_poses = poses[v >= v.max() * (1 - binding_rtol)]
    return AllocationResult(
        choice=choice, cost=_cost(problem, idx), feasible=bool(feasible),
        spec={"position_mm": _scaled(spec_position_um, 1 / MM2UM), "phi_deg": limits.get("phi"),
              "percentile": spec_percentile},
        poses=poses, position_mm=wc.position_mm, phi_deg=wc.phi_deg, binding=binding,
        binding_poses=binding_poses, statistical=statistical, nodes=nodes,
        n_choices=int(np.prod(problem.n_classes.astype(float))), menu=menu, geometry=geometry, seed=seed,
        fixed=problem.fixed_budget, wall_time_s=time.perf_counter() - t0)


def _fixed(budget) -> Budget | None:
    """The budget whose effects and correlations stay fixed, or None (none given, or it has neither)."""
    if budget is None:
        return None
    budget = Budget.load(budget)
    return budget if budget.effects or budget.correlated else None


def _confirm(geometry, problem, check: PercentileCheck, idx, proven: bool) -> dict:
    """The statistical record of the choice (or of the closest one, when none meets the spec), with its
    Monte Carlo confirmation.

    ``confirmed``: an independent Monte Carlo run agrees with the decision.
    Exact method, a choice that meets the spec: no pose's 95 % interval of the
    percentile lies wholly above S (the run does not refute it; the choice is
    tight, so the interval's upper end may pass S by chance). Monte Carlo
    method: the upper end is within S at every pose. A choice that fails: some
    pose's upper end passes S.
    """
    decided = check.record(idx)
    mc = monte_carlo(geometry, problem.budget(_choice(problem, idx)), problem.poses, check.n_samples,
                     rng=child_seed(check.seed, 1), percentiles=(check.q,))
    low, high = mc.position_pct_ci[:, 0, 0], mc.position_pct_ci[:, 0, 1]
    worst = int(np.argmax(high))
    exact = decided["method"] == "exact"
    agrees = bool(np.all(low <= check.S)) if exact else bool(high[worst] <= check.S)
    confirmed = agrees if decided["met"] else bool(high[worst] > check.S)
    return {"percentile": check.q, "method": decided["method"], "exceedance": decided["value"] if exact else None,
            "screen_mm": float(problem.envelopes(idx)["screen"].max()),
            "percentile_mm": float(mc.position_pct[worst, 0]), "ci_high_mm": float(high[worst]),
            "pose": problem.poses[worst], "n_samples": check.n_samples, "seed": check.seed,
            "checks": check.checks, "proven": bool(proven), "confirmed": confirmed}


def allocation_front(geometry, classes, region, *, output: str = "position",
                     spec_position_um: float | None = None, spec_phi_arcsec: float | None = None,
                     grid: int = 41, phi_deg: float | None = None, k_sigma: float | None = None,
                     max_points: int = 100, progress: bool | None = None, budget=None) -> pd.DataFrame:
    """The cost-accuracy Pareto front: the least cost of every reachable worst case of ``output``.

    Swept by repeated exact allocation, each asking for a worst case strictly
    below the last one found (the epsilon-constraint method); the spec of the
    other output, if given, holds at every point. ``progress`` reports each
    point found on stderr (default: when stderr is a terminal); the count of
    points is not known in advance, so the bar runs against ``max_points``.
    ``budget``: its ``[effects]`` stay fixed at every point, as in :func:`allocate`.

    Returns
    -------
    DataFrame
        Tidy: ``point`` (0 = cheapest), ``cost``, ``output`` (position, phi),
        ``statistic`` (worst_case), ``value``, ``unit`` (mm, deg), and one
        column per input with its class.
    """
    if output not in ("position", "phi"):
        raise AllocationError(f"output must be 'position' or 'phi', got {output!r}")
    geometry, menu = Geometry.load(geometry), ClassMenu.load(classes)
    problem = Problem(geometry, menu, region_poses(region, grid, phi_deg), k_sigma=k_sigma, fixed=_fixed(budget))
    side = {"position": _scaled(spec_position_um, 1 / MM2UM), "phi": _scaled(spec_phi_arcsec, 1 / DEG2ARCSEC)}
    side[output] = None
    points, limit = [], None
    bar = Progress(max_points, "allocate: Pareto front", progress)
    while len(points) < max_points:
        idx, _ = least_cost(problem, {**side, output: limit})
        if idx is None:
            break
        bar.update()
        env = {q: float(v.max()) for q, v in problem.envelopes(idx).items()}
        point = (_cost(problem, idx), env, _choice(problem, idx))
        if points and point[0] <= points[-1][0]:
            points[-1] = point                          # same cost, smaller worst case: the old point is dominated
        else:
            points.append(point)
        limit = env[output] * (1 - 1e-9)
    bar.total = max(len(points), 1)
    bar.close()
    rows = [{"point": k, "cost": cost, "output": q, "statistic": "worst_case", "value": env[q],
             "unit": "mm" if q == "position" else "deg", **choice}
            for k, (cost, env, choice) in enumerate(points) for q in ("position", "phi")]
    return pd.DataFrame(rows, columns=["point", "cost", "output", "statistic", "value", "unit", *problem.inputs])


def front_records(front: pd.DataFrame) -> list[dict]:
    """The points of a tidy front as JSON-ready dicts: ``cost``, ``worst_case_position_um``, ``worst_case_phi_arcsec``.

    Cheapest first; empty when no choice meets the side spec.
    """
    wide = front.pivot(index="point", columns="output", values="value")
    cost = front.groupby("point")["cost"].first()
    return [{"cost": float(cost[k]), "worst_case_position_um": MM2UM * float(row["position"]),
             "worst_case_phi_arcsec": DEG2ARCSEC * float(row["phi"])} for k, row in wide.iterrows()]
