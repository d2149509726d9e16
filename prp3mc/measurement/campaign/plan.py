"""Planning a campaign: poses, visit order and approach directions that make the listed effects detectable.

:func:`plan_campaign` chooses ``N`` poses of the workspace to visit ``V``
times each and the order and approach directions of the visits, so that
the discrepancy workflow (:mod:`~prp3mc.measurement.discrepancy.workflow`) can see and
tell apart the listed candidate effects:

1. **Candidates.** A grid over the geometry's test region (its preset
   region, or one given) at orientations from -5 to +5 deg (every pose of
   the reference regions is reachable there), the unreachable ones left out.
2. **Information.** Visits draw the budget's errors afresh (repeatable
   fraction 0), so the ``V`` measurements of a pose are independent with
   covariance ``W_p = Sigma_p + N``. Their Fisher information about the
   listed effects' values and the nuisances (registration, drift) is
   ``sum_m X_m' W_p^-1 X_m`` with ``X_m`` the signatures, each pose's visits
   assumed spread evenly through the campaign (interleaved rounds), with a
   balanced pattern of approach directions (half from each side, per leg
   where a backlash is listed).
3. **D-optimal poses.** The nuisances are profiled out (the Schur
   complement of the information) and the ``N`` poses maximise the log
   determinant of what is left (greedy, then exchange moves until none
   improves it): the effects are then as detectable and as separable from
   each other and from the nuisances as the candidates allow.
4. **Order.** The visits go in ``V`` rounds, each round in a random order
   (so the drift is separable from every effect: each pose is measured
   early and late); of :data:`N_ORDERS` random orders the one with the
   largest criterion is kept, with the measurement times it implies (the
   simulator's moves, :func:`~prp3mc.measurement.campaign.simulate.visit_times`, or
   spread evenly over the minutes given).

The temperature cannot be planned: thermal expansion is evaluated with an
assumed temperature (rising steadily from ``temperature_C[0]`` to
``temperature_C[1]`` over the campaign, the case that hides it best in a
drift); the plan's part is the order and the revisits.

The reported smallest detectable value of each effect and the confounds
are computed by the analysis's own engine on the planned campaign
(:func:`~prp3mc.measurement.discrepancy.workflow.detectable_in`,
:func:`~prp3mc.measurement.naming.confounds.design_confounds`), next to those of
a grid of the same size for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..._rng import resolve_rng
from ..._result import freeze, short_repr
from ..._version import __version__
from ...errors import CampaignError, ParameterError
from ...kinematics.chain import feasible, inverse_kinematics
from ...kinematics.geometry import REGION_PRESETS, Geometry, Region
from ...output import write_text
from ...provenance import versions
from ...model.budget import Budget
from ...model.linear import linear_model
from .data import CMD_COLUMNS, DIR_COLUMNS, MEAS_COLUMNS, MIN_POSES, Campaign
from ..naming.confounds import design_confounds
from ...model.effects import EffectKind, check_leads
from ..forward.signatures import effect, signatures
from ..estimation.likelihood import Engine
from ..estimation.nuisance import DRIFT, NUISANCE_NAMES, REGISTRATION, nuisance_signatures
from ..forward.prediction import noise_cov
from .simulate import visit_times
from ..discrepancy.updated import base_name

__all__ = ["CampaignPlan", "plan_campaign", "PHI_CANDIDATES_DEG", "MAX_CANDIDATES", "N_ORDERS"]

#: Orientations of the candidate poses, deg.
PHI_CANDIDATES_DEG = (-5.0, -2.5, 0.0, 2.5, 5.0)
#: Candidate positions per side of the region.
_GRID = 9
#: Most candidate poses (those of the grid the geometry reaches are kept).
MAX_CANDIDATES = _GRID ** 2 * len(PHI_CANDIDATES_DEG)
#: Random visit orders compared.
N_ORDERS = 24
_RIDGE = 1e-10


@dataclass(frozen=True, slots=True)
class CampaignPlan:
    """A planned campaign (module notes) and what it can see.

    Attributes
    ----------
    geometry : Geometry
    budget : Budget
    effects : tuple of str
        The candidate effects planned for.
    poses : ndarray, shape (N, 3)
        The chosen poses ``[x_mm, y_mm, phi_deg]``.
    order : ndarray of int, shape (M,)
        The visits, indices into ``poses``, in the planned order.
    direction : ndarray, shape (M, 3)
        Commanded approach direction of each actuator, +-1 (written for the legs in ``dir_legs``).
    dir_legs : tuple of int
        0-based legs with a backlash among ``effects`` (their ``dir_i`` columns are written).
    time_s : ndarray, shape (M,)
        Planned time of each visit, s.
    temperature_C : ndarray, shape (M,)
        The temperature assumed for thermal expansion (not planned: ``temp_C`` is left to measure).
    detectable : dict
        Effect -> smallest value named with probability ``power`` (its unit; inf: the campaign cannot see it).
    unseen : dict
        Effect -> why the plan cannot see it (invisible, or exactly confounded with a nuisance).
    reference : dict
        The same for a grid of the region with as many poses and visits (``reference_layout``).
    reference_layout : str
    confounded : tuple of dict
        The confounds of the planned campaign that involve the effects (``confounded`` entries).
    criterion : dict
        ``log_det`` of the profiled information of the plan and of the reference.
    settings : dict
        Every setting the plan was made with (instrument noise, power, alpha, registration, minutes, seed).
    """

    geometry: Geometry
    budget: Budget
    effects: tuple
    poses: np.ndarray
    order: np.ndarray
    direction: np.ndarray
    dir_legs: tuple
    time_s: np.ndarray
    temperature_C: np.ndarray
    detectable: dict
    unseen: dict
    reference: dict
    reference_layout: str
    confounded: tuple
    criterion: dict
    settings: dict

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "effects", "poses", "detectable")

    @property
    def n_measurements(self) -> int:
        return int(self.order.size)

    def to_frame(self) -> pd.DataFrame:
        """The campaign template (README *File formats*): measured columns and ``temp_C`` empty."""
        return _template(self.poses, self.order, self.direction, self.dir_legs, self.time_s)

    def write(self, path) -> Path:
        """Write the template as CSV (atomically); measured cells and ``temp_C`` empty."""
        path = Path(path)
        write_text(path, self.to_frame().to_csv(index=False, float_format="%.6g"))
        return path

    def campaign(self) -> Campaign:
        """The plan as a campaign measured without error, at the assumed temperatures (only its layout matters)."""
        return _as_campaign(self.geometry, self.to_frame(), self.temperature_C)

    def to_dict(self) -> dict:
        """``{"detectable", "confounded", "reference", ...}`` with ``inputs`` and ``versions`` (SPEC §11)."""
        return {
            "inputs": {"geometry": {"name": self.geometry.name}, "budget": {"name": self.budget.name},
                       "effects": list(self.effects), "n_poses": int(self.poses.shape[0]),
                       "n_measurements": self.n_measurements, **self.settings},
            "versions": versions(),
            "detectable": _finite(self.detectable), "not_detectable": dict(self.unseen),
            "confounded": [dict(c) for c in self.confounded],
            "reference": {"layout": self.reference_layout, "detectable": _finite(self.reference)},
            "criterion": dict(self.criterion),
            "poses": [{"x_mm": float(x), "y_mm": float(y), "phi_deg": float(p)} for x, y, p in self.poses],
            "temperature": {"planned": False, "assumed_C": [float(self.temperature_C[0]),
                                                            float(self.temperature_C[-1])],
                            "note": "the plan cannot set the temperature; thermal expansion is evaluated with it "
                                    "rising steadily over the campaign (the case that hides it best in a drift). "
                                    "The plan orders the visits in interleaved rounds (every pose measured early "
                                    "and late); cycle the temperature to separate thermal expansion from drift"},
            "power": self.settings["power"], "version": __version__,
        }


def _finite(values: dict) -> dict:
    """Detectable values for JSON: an effect the campaign cannot see is null (its reason is in ``not_detectable``)."""
    return {n: (float(v) if np.isfinite(v) else None) for n, v in values.items()}


def _unseen(engine: Engine, effects) -> dict:
    """Why the campaign of ``engine`` cannot see each effect of ``effects`` it cannot see."""
    out = {}
    for name in effects:
        if name in engine.invisible:
            out[name] = "its signature vanishes over the planned poses (invisible)"
        elif name in engine.confounded:
            out[name] = f"exactly confounded with the {engine.confounded[name]}"
        elif name in engine.not_testable:
            out[name] = engine.not_testable[name]
    return out


def _template(poses, order, direction, dir_legs, time_s) -> pd.DataFrame:
    """A campaign template: commanded poses in visiting order, measured cells empty, ``dir_i`` of ``dir_legs``."""
    frame = pd.DataFrame({"pose_id": [f"P{k + 1:03d}" for k in order]})
    for k, col in enumerate(CMD_COLUMNS):
        frame[col] = poses[order, k]
    for col in MEAS_COLUMNS:
        frame[col] = np.nan
    for i in dir_legs:
        frame[DIR_COLUMNS[i]] = direction[:, i].astype(int)
    frame["temp_C"] = np.nan
    frame["time_s"] = time_s
    return frame


def _as_campaign(geometry: Geometry, template: pd.DataFrame, temperature_C: np.ndarray) -> Campaign:
    """A template as a campaign measured without error at the given temperatures (for planning)."""
    frame = template.copy()
    for cmd, meas in zip(CMD_COLUMNS, MEAS_COLUMNS):
        frame[meas] = frame[cmd]
    frame["temp_C"] = temperature_C
    return Campaign.from_frame(frame, geometry, "planned campaign")


def _region(geometry: Geometry, region: Region | None) -> Region:
    if region is not None:
        return region
    name = base_name(geometry.name)
    if name not in REGION_PRESETS:
        raise CampaignError(f"geometry {geometry.name!r} has no preset test region: give the region to plan over")
    return Region.from_preset(name)


def _candidates(geometry: Geometry, region: Region) -> np.ndarray:
    """Reachable candidate poses (C, 3): a grid of the region at every orientation of PHI_CANDIDATES_DEG."""
    base = region.grid(_GRID).reshape(-1, 3)
    poses = np.concatenate([np.column_stack([base[:, :2], np.full(len(base), phi)]) for phi in PHI_CANDIDATES_DEG])
    return poses[feasible(geometry, poses)]


def _balanced(n_visits: int, shape: tuple, rng) -> np.ndarray:
    """Approach directions (*shape, n_visits): per pose and leg half the visits from each side, shuffled."""
    base = np.where(np.arange(n_visits) < (n_visits + 1) // 2, 1.0, -1.0)
    return rng.permuted(np.broadcast_to(base, shape + (n_visits,)).copy(), axis=-1)


class _Information:
    """Per-measurement whitened signatures of the listed effects and the nuisances, and the plan criterion."""

    def __init__(self, geometry, budget, effects, noise, registration: bool, temperature: tuple):
        self.geometry, self.effects, self.temperature = geometry, list(effects), temperature
        self.budget = budget.without_effects()
        self.noise = noise
        self.nuis = [j for j, n in enumerate(NUISANCE_NAMES) if n in DRIFT or (registration and n in REGISTRATION)]

    def whitening(self, poses: np.ndarray) -> np.ndarray:
        """Per pose ``L`` (P, 3, 3) with ``L W_p L' = I``: the visits' whitening, the same for every order."""
        _, cov = linear_model(self.geometry, self.budget, poses, check=False).moments()
        return np.linalg.inv(np.linalg.cholesky(cov + self.noise + 1e-12 * np.eye(3)))

    def whitened(self, poses: np.ndarray, index: np.ndarray, direction: np.ndarray, s: np.ndarray,
                 L: np.ndarray | None = None) -> np.ndarray:
        """Whitened columns ``[effects, nuisances]`` of measurements (M, 3, K + n) at poses[index]
        (``L``: :meth:`whitening` of ``poses``, computed when not given)."""
        temp = self.temperature[0] + (self.temperature[1] - self.temperature[0]) * s
        G = signatures(self.geometry, poses, index, self.effects, direction, temp)
        H = nuisance_signatures(poses[index], s)[:, :, self.nuis]
        L = self.whitening(poses) if L is None else L
        return np.einsum("mij,mjk->mik", L[index], np.concatenate([G, H], axis=2))

    def criterion(self, info: np.ndarray) -> np.ndarray:
        """log det of the information (..., d, d) with the nuisances profiled out (Schur complement)."""
        k = sum(effect(n).dof for n in self.effects)          # the effects' columns (a cyclic error: two)
        A, B, C = info[..., :k, :k], info[..., :k, k:], info[..., k:, k:]
        ridge = _RIDGE * (np.trace(C, axis1=-2, axis2=-1)[..., None, None] + 1.0) * np.eye(C.shape[-1])
        S = A - B @ np.linalg.solve(C + ridge, np.swapaxes(B, -1, -2))
        S = S + _RIDGE * (np.trace(S, axis1=-2, axis2=-1)[..., None, None] / k + 1e-300) * np.eye(k)
        return np.linalg.slogdet(S)[1]


def _choose(per_pose: np.ndarray, n: int, crit) -> np.ndarray:
    """Indices of ``n`` candidates maximising ``crit`` of their summed information: greedy, then exchanges."""
    C = per_pose.shape[0]
    chosen: list[int] = []
    total = np.zeros(per_pose.shape[1:])
    for _ in range(n):
        free = np.setdiff1d(np.arange(C), chosen)
        best = int(free[np.argmax(crit(total + per_pose[free]))])
        chosen.append(best)
        total += per_pose[best]
    current = float(crit(total))
    for _ in range(20):                                   # exchange sweeps until none improves
        improved = False
        for pos in range(n):
            free = np.setdiff1d(np.arange(C), chosen)
            trial = total - per_pose[chosen[pos]] + per_pose[free]
            values = crit(trial)
            j = int(np.argmax(values))
            if values[j] > current + 1e-9:
                total = trial[j]
                chosen[pos], current, improved = int(free[j]), float(values[j]), True
        if not improved:
            break
    return np.array(sorted(chosen))


def _elapsed(b: np.ndarray) -> np.ndarray:
    """Seconds since the first measurement of visits at slider positions ``b`` (M, 3) mm (the simulator's moves)."""
    t = visit_times(b)
    return t - t[0]


def _schedule(info: _Information, geometry, poses, n_visits, direction, minutes, rng):
    """The best of N_ORDERS random interleaved orders: order (M,), directions (M, 3), times (M,), criterion."""
    P = poses.shape[0]
    b, _ = inverse_kinematics(geometry, poses, check=False)
    L = info.whitening(poses)
    best = None
    for _ in range(N_ORDERS):
        order = np.concatenate([rng.permutation(P) for _ in range(n_visits)])
        dirs = direction[order, :, np.arange(order.size) // P]       # a pose's k-th visit is in round k
        t = np.linspace(0.0, 60.0 * minutes, order.size) if minutes is not None else _elapsed(b[order])
        s = (t - t[0]) / max(t[-1] - t[0], 1e-12)
        Z = info.whitened(poses, order, dirs, s, L)
        value = float(info.criterion(np.einsum("mik,mil->kl", Z, Z)))
        if best is None or value > best[-1]:
            best = (order, dirs, t, s, value)
    return best


def _reference(info: _Information, geometry, region: Region, n_poses: int, n_visits: int, dir_legs,
               minutes, temperature_C, rng) -> tuple[Campaign, float, str]:
    """The layout a plan is compared with: a square grid of the region with about ``n_poses`` poses, phi
    cycling -4, 0, 4 deg, ``n_visits`` rounds in random orders, random approach directions; its campaign,
    criterion and description."""
    side = max(int(round(np.sqrt(n_poses))), 2)
    poses = region.grid(side).reshape(-1, 3)
    poses[:, 2] = np.resize([-4.0, 0.0, 4.0], len(poses))
    order = np.concatenate([rng.permutation(len(poses)) for _ in range(n_visits)])
    dirs = rng.choice([-1.0, 1.0], size=(order.size, 3))
    b, _ = inverse_kinematics(geometry, poses[order], check=False)
    t = np.linspace(0.0, 60.0 * minutes, order.size) if minutes is not None else _elapsed(b)
    s = (t - t[0]) / max(t[-1] - t[0], 1e-12)
    Z = info.whitened(poses, order, dirs, s)
    value = float(info.criterion(np.einsum("mik,mil->kl", Z, Z)))
    temps = temperature_C[0] + (temperature_C[1] - temperature_C[0]) * s
    campaign = _as_campaign(geometry, _template(poses, order, dirs, dir_legs, t), temps)
    return campaign, value, (f"{side} x {side} grid of the region, phi cycling -4, 0, 4 deg, {n_visits} visits "
                             "in random rounds, random approach directions")


def plan_campaign(geometry: Geometry, budget: Budget, effects, n_poses: int, n_visits: int, *,
                  minutes: float | None = None, region: Region | None = None,
                  temperature_C: tuple[float, float] = (20.0, 28.0), instrument_sigma_mm: float = 0.002,
                  instrument_sigma_deg: float = 0.0005, registration: bool = True, power: float = 0.9,
                  alpha: float = 0.01, rng: "None | int | np.random.Generator" = None) -> CampaignPlan:
    """Plan a campaign that makes ``effects`` as detectable and separable as the workspace allows.

    Parameters
    ----------
    geometry, budget
        The model the campaign will be analysed with.
    effects : sequence of str
        Systematic effects of the library (SPEC §5) to plan for.
    n_poses, n_visits : int
        Distinct poses, and visits of each (``n_poses * n_visits`` measurements).
    minutes : float, optional
        Spread the planned times evenly over this many minutes (default: the
        simulator's moves at 20 mm/s and 4 s per measurement).
    region : Region, optional
        Where to choose poses (default: the geometry's preset test region).
    temperature_C : (start, end)
        The temperature assumed for thermal expansion, rising steadily (not planned).
    instrument_sigma_mm, instrument_sigma_deg : float
        Instrument noise the campaign will have.
    registration : bool
        Whether the analysis will fit the instrument's registration.
    power, alpha : float
        The detectable value is named with probability ``power`` at the
        workflow's family-wise level ``alpha``.
    rng : None, int or numpy.random.Generator
        Randomness of the directions and orders (the seed is recorded).

    Returns
    -------
    CampaignPlan

    Raises
    ------
    ParameterError
        No effect, or a spread (unknown names: :class:`~prp3mc.errors.BudgetError`).
    CampaignError
        Too few poses or visits, or more poses than the region has candidates.
    """
    from ..discrepancy.workflow import detectable_in                        # the workflow imports the engine this uses
    seed, rng = resolve_rng(rng)
    effects = tuple(dict.fromkeys(effects))
    if not effects:
        raise ParameterError("plan: list at least one effect")
    for name in effects:
        if not effect(name).systematic:
            raise ParameterError(f"plan: {name} is a spread; plan for systematic effects (offsets, scale_i, "
                              "backlash_i, thermal, cyclic_i)")
    check_leads(effects, geometry, "plan: ")
    n_poses, n_visits = int(n_poses), int(n_visits)
    if n_poses < MIN_POSES or n_visits < 1:
        raise CampaignError(f"plan: at least {MIN_POSES} poses and 1 visit, got {n_poses} and {n_visits}")
    if minutes is not None and not (np.isfinite(minutes) and minutes > 0):
        raise CampaignError(f"plan: minutes must be > 0, got {minutes}")
    region = _region(geometry, region)
    candidates = _candidates(geometry, region)
    if n_poses > len(candidates):
        raise CampaignError(f"plan: {n_poses} poses asked, the region has {len(candidates)} candidates")
    noise = noise_cov(instrument_sigma_mm, instrument_sigma_deg)
    info = _Information(geometry, budget, effects, noise, registration, temperature_C)
    dir_legs = tuple(sorted({effect(n).leg for n in effects if effect(n).kind == EffectKind.BACKLASH}))
    C = len(candidates)
    direction = _balanced(n_visits, (C, 3), rng)                      # (C, 3, V)
    s_visit = (np.arange(n_visits) + 0.5) / n_visits                  # interleaved rounds: spread through time
    index = np.repeat(np.arange(C), n_visits)
    Z = info.whitened(candidates, index, np.moveaxis(direction, 2, 1).reshape(-1, 3), np.tile(s_visit, C))
    per_pose = np.einsum("mik,mil->mkl", Z, Z).reshape(C, n_visits, Z.shape[2], Z.shape[2]).sum(1)
    chosen = _choose(per_pose, n_poses, info.criterion)
    poses = candidates[chosen]
    order, dirs, t, s, value = _schedule(info, geometry, poses, n_visits, direction[chosen], minutes, rng)
    dirs = np.where(np.isin(np.arange(3), dir_legs), dirs, 1.0)
    temps = temperature_C[0] + (temperature_C[1] - temperature_C[0]) * s
    planned = _as_campaign(geometry, _template(poses, order, dirs, dir_legs, t), temps)
    ref_campaign, ref_value, layout = _reference(info, geometry, region, n_poses, n_visits, dir_legs, minutes,
                                                 temperature_C, rng)
    engine, ref_engine = (Engine(geometry, budget, c, noise, registration=registration)
                          for c in (planned, ref_campaign))
    detect = {n: detectable_in(engine, n, power=power, alpha=alpha) for n in effects}
    ref = {n: detectable_in(ref_engine, n, power=power, alpha=alpha) for n in effects}
    confounded = design_confounds(engine, effects)
    return CampaignPlan(
        geometry=geometry, budget=budget, effects=effects, poses=poses, order=order, direction=dirs,
        dir_legs=dir_legs, time_s=t, temperature_C=temps, detectable=detect, unseen=_unseen(engine, effects),
        reference=ref,
        reference_layout=layout, confounded=tuple(confounded),
        criterion={"log_det": value, "reference_log_det": ref_value},
        settings={"instrument_sigma_mm": instrument_sigma_mm, "instrument_sigma_deg": instrument_sigma_deg,
                  "registration": registration, "power": power, "alpha": alpha, "minutes": minutes,
                  "temperature_C": list(temperature_C), "seed": seed, "n_visits": n_visits,
                  "candidates": int(C), "region": {"x_mm": list(region.x_mm), "y_mm": list(region.y_mm)},
                  "phi_candidates_deg": list(PHI_CANDIDATES_DEG)})
