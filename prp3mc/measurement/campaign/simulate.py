"""Simulated measurement campaigns with hidden effects, on the exact nonlinear chain.

:func:`simulate_campaign` makes campaigns with the exact nonlinear model and
the realities a metrology campaign carries: budget errors that are drawn
afresh at every visit or partly repeat per pose, approach directions, a
temperature drift, the instrument's registration to the machine and its
drift in time, instrument noise, gross outliers (a lost tracker beam), and
hidden effects of the library (:mod:`prp3mc.measurement.forward.signatures`), several at
once if wanted.

Randomness (one seed, recorded in ``metadata["seed"]``): the root generator
draws, in this order, the visiting order (``visit_order="random"``), the approach directions (``both``),
the budget errors of every visit and the instrument noise; the per-pose
errors (``repeatable_fraction``) come from the stream
``child_seed(seed, 1)`` and the outliers from ``child_seed(seed, 2)``. So a
campaign with all new realities off has the same numbers as before they
existed, and switching one reality on leaves the others' draws unchanged.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..._rng import child_seed, resolve_rng
from ..._version import __version__
from ...errors import BudgetError, CampaignError
from ...kinematics.chain import as_poses, check_poses, inverse_kinematics
from ...kinematics.exact import exact_pose_error
from ...kinematics.geometry import Geometry
from ...model.budget import Budget, parse_input
from ...model.effects import EffectKind, check_leads, effect_value
from ...units import DEG2RAD
from .data import CMD_COLUMNS, DIR_COLUMNS, MAX_ERROR, MEAS_COLUMNS, Campaign
from ..forward.signatures import effect, offset_errors, slider_error, spread_budget

__all__ = ["simulate_campaign", "check_plausible", "visit_times", "frame_transform", "SETTLE_S", "SLIDER_SPEED_MM_S",
           "PLAUSIBLE", "PLAUSIBLE_NOISE"]

#: Seconds from arriving at a pose to the measurement (settling plus the instrument's averaging).
SETTLE_S = 4.0
#: Slider speed of a move between poses, mm/s (the slowest actuator sets the move's duration).
SLIDER_SPEED_MM_S = 20.0
#: Sub-streams under the root seed (see the module notes).
_STREAM_REPEATS, _STREAM_OUTLIERS = 1, 2
#: Largest plausible hidden value per unit of an effect (mm, deg, 1, 1/K), and of the instrument's noise sd
#: (mm, deg): a larger one is a value typed in another unit (20 for a 20 µm backlash, 2 for a 2 µm noise).
#: A misassembled machine's few degrees or millimetres stay below them (issue 24's large errors).
PLAUSIBLE = {"mm": 10.0, "deg": 10.0, "1": 0.05, "1/K": 1e-3}
PLAUSIBLE_NOISE = {"mm": 0.5, "deg": 0.5}


def visit_times(b: np.ndarray) -> np.ndarray:
    """Time of each measurement since the campaign began, from the slider moves between them.

    Every measurement comes :data:`SETTLE_S` after the move that reaches it,
    and a move lasts as long as its largest slider travel at
    :data:`SLIDER_SPEED_MM_S` (the machine starts at the first pose).

    Parameters
    ----------
    b : ndarray, shape (M, 3)
        Commanded slider positions of the measurements in visiting order, mm.

    Returns
    -------
    ndarray, shape (M,)
        Seconds, increasing.
    """
    move = np.abs(np.diff(b, axis=0, prepend=b[:1])).max(axis=1) / SLIDER_SPEED_MM_S
    return np.cumsum(move + SETTLE_S)


def frame_transform(poses: np.ndarray, dx_mm, dy_mm, dphi_deg) -> np.ndarray:
    """Poses of the machine frame seen in an instrument frame (planar rigid transform).

    The pose is rotated about the instrument's origin by ``dphi_deg``, then
    translated by ``(dx_mm, dy_mm)``; its orientation gains ``dphi_deg``.

    Parameters
    ----------
    poses : ndarray, shape (M, 3)
        ``[x_mm, y_mm, phi_deg]`` in the machine frame.
    dx_mm, dy_mm, dphi_deg : float or ndarray, shape (M,)
        The transform (one per pose when arrays: a drifting instrument).

    Returns
    -------
    ndarray, shape (M, 3)
        The same poses in the instrument frame.
    """
    a = np.asarray(dphi_deg, dtype=float) * DEG2RAD
    c, s = np.cos(a), np.sin(a)
    x, y = poses[:, 0], poses[:, 1]
    return np.stack([c * x - s * y + dx_mm, s * x + c * y + dy_mm, poses[:, 2] + dphi_deg], axis=1)


def _triple(value, name: str) -> tuple[float, float, float] | None:
    """``(dx_mm, dy_mm, dphi_deg)`` as three finite floats, or None."""
    if value is None:
        return None
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise CampaignError(f"{name} must be three finite numbers (dx_mm, dy_mm, dphi_deg), got {value!r}")
    return tuple(float(t) for t in v)


def _outlier_setting(value) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        fraction, size = (float(t) for t in value)
    except (TypeError, ValueError):
        raise CampaignError(f"outliers must be (fraction, size_mm), got {value!r}") from None
    if not (0.0 <= fraction <= 1.0 and 0.0 < size < MAX_ERROR[0]):
        raise CampaignError(f"outliers: fraction must lie in [0, 1] and size_mm in (0, {MAX_ERROR[0]:g}), "
                            f"got ({fraction:g}, {size:g})")
    return fraction, size


def _circular_mean(law) -> np.ndarray:
    """``E[u(zeta)] = [E cos zeta, E sin zeta]`` of a contact-angle law in degrees (midpoint rule on its ppf)."""
    zeta = law.ppf((np.arange(4096) + 0.5) / 4096) * DEG2RAD
    return np.array([np.cos(zeta).mean(), np.sin(zeta).mean()])


def _clearance(S: np.ndarray, k: int, z: int) -> np.ndarray:
    """Clearance vectors ``rho u(zeta)`` (n, 2) of input samples ``S`` (n, d): rho in column k, zeta (deg) in z."""
    angle = S[:, z] * DEG2RAD
    return S[:, k, None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def _repeat_errors(budget: Budget, X: np.ndarray, pose_of_visit: np.ndarray, n_poses: int, r: float,
                   rng: np.random.Generator) -> np.ndarray:
    """Budget inputs of every visit: a part drawn once per pose and a part drawn at every visit.

    Every input becomes ``mean + sqrt(r) (A - mean) + sqrt(1 - r) (B - mean)``
    with ``A`` the pose's draw and ``B`` the visit's (``X``). A clearance
    enters the chain as the vector ``rho_i u(zeta_i)``, so it is that vector
    that is split so, and turned back into a size and a contact angle. The
    mean and the covariance of every input, and of the clearance vectors,
    are exact; the covariance between two visits of a pose is ``r`` times
    the budget's. The law's shape is not kept: ``A`` and ``B`` add up (a
    uniform law becomes a trapezoid and can leave its bounds), while the
    within-pose scatter ``sqrt(1 - r) (B - B_bar)`` is the fresh-draw
    scatter scaled.
    """
    A = budget.sample(n_poses, rng)[pose_of_visit]
    mean = budget.means()
    out = mean + np.sqrt(r) * (A - mean) + np.sqrt(1.0 - r) * (X - mean)
    names = budget.names
    for k, name in enumerate(names):
        family, leg = parse_input(name)
        if family != "rho":
            continue
        z = names.index(f"zeta_{leg + 1}")
        centre = mean[k] * _circular_mean(budget.inputs[names[z]])
        v = (centre + np.sqrt(r) * (_clearance(A, k, z) - centre)
             + np.sqrt(1.0 - r) * (_clearance(X, k, z) - centre))
        out[:, k] = np.hypot(v[:, 0], v[:, 1])
        out[:, z] = np.mod(np.arctan2(v[:, 1], v[:, 0]) / DEG2RAD, 360.0)
    return out


def check_plausible(effects: dict, instrument_sigma_mm: float, instrument_sigma_deg: float, *,
                    labels: tuple[str, str, str] = ("effects", "instrument_sigma_mm", "instrument_sigma_deg")) -> None:
    """Refuse, in one line, a hidden effect or an instrument noise too large for its unit (a value in µm or
    arcsec given where mm or deg are meant): above :data:`PLAUSIBLE` or :data:`PLAUSIBLE_NOISE`.

    Parameters
    ----------
    effects : dict of str to float or complex
        Hidden effects in their units (a cyclic error's phasor: its amplitude is judged); unknown names are
        skipped (:func:`simulate_campaign` names them).
    instrument_sigma_mm, instrument_sigma_deg : float
        Standard deviations of the instrument noise, mm and deg.
    labels : (str, str, str)
        How the message names the effects and the two noise settings (the CLI gives its options).

    Raises
    ------
    CampaignError
        A value above its unit's plausible bound.
    """
    for name, value in effects.items():
        try:
            unit = effect(name).unit
        except (BudgetError, KeyError, ValueError):
            continue                        # an unknown name: the simulation names it
        if abs(value) > PLAUSIBLE.get(unit, np.inf):
            raise CampaignError(f"{labels[0]} {name}={value:g}: larger than any {unit} value a machine shows "
                                f"({PLAUSIBLE[unit]:g}); check units (mm, deg, 1, 1/K: 20 µm is 0.02)")
    for option, sigma, unit in ((labels[1], instrument_sigma_mm, "mm"), (labels[2], instrument_sigma_deg, "deg")):
        if sigma > PLAUSIBLE_NOISE[unit]:
            raise CampaignError(f"{option} {sigma:g}: an instrument noise sd above {PLAUSIBLE_NOISE[unit]:g} {unit}; "
                                f"check units ({unit}: 2 µm is 0.002 mm, 2 arcsec is 0.00056 deg)")


def _template(plan, geometry: Geometry) -> Campaign:
    """A campaign template (measured columns empty) validated as a campaign whose measurements equal the commands."""
    if isinstance(plan, Campaign):
        return plan
    frame = pd.DataFrame(plan).rename(columns=lambda c: str(c).strip()).dropna(axis=1, how="all")  # empty columns
    for cmd, meas in zip(CMD_COLUMNS, MEAS_COLUMNS):
        if cmd in frame.columns:
            frame[meas] = frame[cmd]
    return Campaign.from_frame(frame, geometry, "campaign plan")


def _plan_times(template: Campaign) -> np.ndarray:
    """The template's ``time_s``: finite and never decreasing."""
    t = pd.to_numeric(template.extra["time_s"], errors="coerce").to_numpy(dtype=float)
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise CampaignError("campaign plan: time_s must be finite numbers that never decrease (row order is time)")
    return t


def simulate_campaign(geometry: Geometry, budget: Budget, poses, n_repeats: int = 8, *,
                      effects: dict | None = None, approach: str = "both",
                      temp_drift_C: tuple[float, float] | None = (20.0, 28.0),
                      instrument_sigma_mm: float = 0.002, instrument_sigma_deg: float = 0.0005,
                      registration: tuple[float, float, float] | None = None,
                      drift: tuple[float, float, float] | None = None,
                      outliers: tuple[float, float] | None = None,
                      repeatable_fraction: float = 0.0,
                      slider_error_fn=None, pose_error_fn=None, visit_order: str = "random",
                      rng: "None | int | np.random.Generator" = None,
                      plan: "pd.DataFrame | Campaign | None" = None) -> Campaign:
    """Simulate a measurement campaign with the exact nonlinear model.

    The campaign visits every pose once per round, in a fresh random order
    each round (or in the order given: ``visit_order``), for ``n_repeats`` rounds; the temperature drifts linearly in
    time over the campaign. Every measurement has a time (``time_s``, from
    the moves between poses: :func:`visit_times`). By default every
    measurement draws fresh budget errors (a clearance settles at a new
    contact angle, an encoder reads a new count error each time the pose is
    approached) and fresh instrument noise, and the instrument is perfectly
    registered, does not drift and never loses its beam; each of these
    realities can be switched on.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
        Random errors; spread effects in ``effects`` change its laws. The
        systematic effects of its ``[effects]`` table are part of the
        machine too (with the campaign's directions and temperatures).
    poses : array_like, shape (P, 3), or None
        Commanded poses ``[x_mm, y_mm, phi_deg]`` (any batch shape is
        flattened); None with ``plan``.
    n_repeats : int
        Measurements per pose (1: a one-visit campaign, as a laser tracker's sweep; ignored with ``plan``).
    effects : dict of str to float, optional
        Hidden effects of the library (:data:`~prp3mc.measurement.forward.signatures.EFFECT_NAMES`, in their units); any number
        at once, their pose errors add up through the exact chain (a hidden effect the budget's
        ``[effects]`` also holds adds to its value). A cyclic screw error ``cyclic_i`` is its phasor,
        its amplitude (phase 0) or ``(amplitude_mm, phase_deg)``, and needs ``lead_mm`` of leg i in the geometry.
    approach : {"both", "positive", "negative", "sequence"}
        Approach direction of each actuator: random +-1 per actuator and
        measurement; always +1; always -1; or the sign of the actuator's
        move from the previous pose visited.
    temp_drift_C : (start, end) or None
        Temperature at the first and last measurement, degrees C; None for
        a campaign without a ``temp_C`` column (thermal effects then need it).
    instrument_sigma_mm, instrument_sigma_deg : float
        Standard deviation of the Gaussian measurement noise per coordinate.
    registration : (dx_mm, dy_mm, dphi_deg), optional
        The instrument's frame error: measured poses are the machine's poses
        rotated about the instrument's origin by ``dphi_deg``, then
        translated by ``(dx_mm, dy_mm)`` (:func:`frame_transform`);
        ``phi_meas`` gains ``dphi_deg``.
    drift : (dx_mm, dy_mm, dphi_deg), optional
        Instrument drift from the first to the last measurement, linear in
        ``time_s``: every measured pose is offset by this drift times the
        fraction of the campaign's time elapsed (the drift the discrepancy
        workflow fits; an instrument that turns as it drifts would also turn
        positions, by 1.7 µm per 0.001 deg at 100 mm from its origin).
    outliers : (fraction, size_mm), optional
        ``round(fraction * M)`` measurements, chosen at random, get a gross
        position error of ``size_mm`` in a uniformly random direction of the
        plane (a lost tracker beam; ``phi_meas`` is left alone).
    repeatable_fraction : float in [0, 1]
        Share of the budget's variance that repeats when a pose is revisited
        (0: every visit draws afresh; 1: each pose keeps its errors). Each
        input is ``mean + sqrt(r) (A - mean) + sqrt(1 - r) (B - mean)`` with
        ``A`` drawn once per pose and ``B`` at every visit (a clearance as
        its vector ``rho u(zeta)``). This keeps the mean and the covariance
        exact, and the within-pose scatter has the fresh-draw law scaled by
        ``sqrt(1 - r)``; the law of one visit is not kept (``A`` and ``B``
        add: a uniform law becomes a trapezoid, wider than its bounds).
    slider_error_fn, pose_error_fn : callable, optional
        Effects outside the library, for testing the workflow:
        ``f(commanded (M, 3), b (M, 3), direction (M, 3), temp_C (M,) or None)``
        returning an extra slider error delta b (M, 3) mm, or an extra pose
        error (M, 3) ``[mm, mm, deg]`` added to the exact one.
    visit_order : {"random", "given"}
        Each round visits the poses in a fresh random order, or in the order
        of ``poses`` (a sweep: a raster or serpentine path, as a laser tracker
        measures a workspace).
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7; streams in the module notes);
        the integer seed used is recorded in ``metadata["seed"]``, also when
        a Generator is given.
    plan : DataFrame or Campaign, optional
        A campaign template (SPEC §11: the campaign columns, measured ones
        empty, as ``prp3mc plan`` writes): its rows are the measurements, in
        their order, with their ``pose_id`` and commanded poses, the
        template's ``dir_i`` (instead of ``approach`` for those legs) and ``time_s``
        (instead of :func:`visit_times`) when it has them. No visiting order
        is drawn.

    Returns
    -------
    Campaign
        With a ``time_s`` column. ``metadata`` records the seed, the hidden
        effects, every setting and the rows given outliers
        (``outlier_rows``, 0-based).

    Raises
    ------
    CampaignError
        A setting out of range, or a hidden effect or noise too large for its unit (:func:`check_plausible`).
    """
    seed_used, rng = resolve_rng(rng)
    template = None if plan is None else _template(plan, geometry)
    poses = as_poses(poses if template is None else template.poses).reshape(-1, 3)
    check_poses(geometry, poses)
    n_repeats = int(n_repeats) if template is None else int(template.repeats.max())
    if n_repeats < 1:
        raise CampaignError(f"n_repeats must be at least 1, got {n_repeats}")
    if approach not in ("both", "positive", "negative", "sequence"):
        raise CampaignError(f"approach must be both, positive, negative or sequence, got {approach!r}")
    registration, drift = _triple(registration, "registration"), _triple(drift, "drift")
    outliers = _outlier_setting(outliers)
    r = float(repeatable_fraction)
    if not 0.0 <= r <= 1.0:
        raise CampaignError(f"repeatable_fraction must lie in [0, 1], got {repeatable_fraction!r}")
    if visit_order not in ("random", "given"):
        raise CampaignError(f"visit_order must be random or given, got {visit_order!r}")
    effects = {name: effect_value(name, value) for name, value in dict(effects or {}).items()}
    parsed = [effect(name) for name in effects]          # raises on unknown names
    for e, v in zip(parsed, effects.values()):
        if e.kind is EffectKind.BACKLASH and v < 0:
            raise CampaignError(f"{e.name}: backlash h must be >= 0, got {v}")
    check_plausible(effects, instrument_sigma_mm, instrument_sigma_deg)
    budget.check_geometry(geometry)
    check_leads(effects, geometry, "hidden effect ")
    machine = {name: eff.model_value for name, eff in budget.effects.items()}   # the budget's effects, then the hidden
    for name, value in effects.items():
        machine[name] = machine.get(name, 0.0) + value
    if "thermal" in machine and temp_drift_C is None:
        raise CampaignError("a thermal effect (hidden or in the budget) needs a temperature drift (temp_drift_C)")
    P = poses.shape[0]
    if template is None:
        order = np.concatenate([rng.permutation(P) if visit_order == "random" else np.arange(P)
                                for _ in range(n_repeats)])                  # visiting order
        pose_ids = np.array([f"P{k + 1:03d}" for k in order])
    else:
        order, pose_ids = template.pose_index, template.pose_id
    M = order.size
    cmd = poses[order]
    b_pose, _ = inverse_kinematics(geometry, poses, check=False)
    b = b_pose[order]
    if template is not None and all(template.has_dir):
        direction = np.array(template.direction)
    elif approach == "both":
        direction = rng.choice([-1.0, 1.0], size=(M, 3))
    elif approach == "sequence":
        step = np.diff(b, axis=0, prepend=b[:1] - 1.0)
        direction = np.where(step > 0, 1.0, np.where(step < 0, -1.0, np.nan))
        direction = pd.DataFrame(direction).ffill().fillna(1.0).to_numpy()
    else:
        direction = np.full((M, 3), 1.0 if approach == "positive" else -1.0)
    if template is not None and any(template.has_dir) and not all(template.has_dir):   # prp3mc plan: backlash legs
        direction[:, list(template.has_dir)] = template.direction[:, list(template.has_dir)]
    time_s = visit_times(b) if template is None or "time_s" not in template.extra else _plan_times(template)
    temp = None if temp_drift_C is None else np.linspace(temp_drift_C[0], temp_drift_C[1], M)
    sim_budget = spread_budget(budget.without_effects(), effects)
    X = sim_budget.sample(M, rng)
    if r > 0.0:
        X = _repeat_errors(sim_budget, X, order, P, r, np.random.default_rng(child_seed(seed_used, _STREAM_REPEATS)))
    errors = sim_budget.errors(X)
    for family, value in offset_errors(machine).items():
        errors[family] = errors.get(family, 0.0) + value
    db = slider_error(machine, b, direction, temp, geometry.lead_mm)
    if slider_error_fn is not None:
        db = db + np.asarray(slider_error_fn(cmd, b, direction, temp), dtype=float)
    errors["b"] = errors.get("b", 0.0) + db
    err = exact_pose_error(geometry, cmd, errors, check=False)
    if pose_error_fn is not None:
        err = err + np.asarray(pose_error_fn(cmd, b, direction, temp), dtype=float)
    noise = rng.standard_normal((M, 3)) * np.array([instrument_sigma_mm, instrument_sigma_mm, instrument_sigma_deg])
    attained = cmd + err if registration is None else frame_transform(cmd + err, *registration)
    measured = attained + noise
    if drift is not None:
        elapsed = (time_s - time_s[0]) / (time_s[-1] - time_s[0]) if M > 1 else np.zeros(M)
        measured = measured + elapsed[:, None] * np.asarray(drift)
    outlier_rows: list[int] = []
    if outliers is not None:
        gen = np.random.default_rng(child_seed(seed_used, _STREAM_OUTLIERS))
        rows = np.sort(gen.choice(M, size=int(round(outliers[0] * M)), replace=False))
        angle = gen.uniform(0.0, 2.0 * np.pi, rows.size)
        measured[rows, 0] += outliers[1] * np.cos(angle)
        measured[rows, 1] += outliers[1] * np.sin(angle)
        outlier_rows = rows.tolist()
    frame = pd.DataFrame({"pose_id": pose_ids})
    for k, col in enumerate(CMD_COLUMNS):
        frame[col] = cmd[:, k]
    for k, col in enumerate(MEAS_COLUMNS):
        frame[col] = measured[:, k]
    for k, col in enumerate(DIR_COLUMNS):
        frame[col] = direction[:, k].astype(int)
    if temp is not None:
        frame["temp_C"] = temp
    frame["time_s"] = time_s
    metadata = {"seed": seed_used, "effects": effects, "machine_effects": machine, "n_repeats": n_repeats,
                "visit_order": visit_order, "approach": approach,
                "temp_drift_C": None if temp_drift_C is None else list(temp_drift_C),
                "instrument_sigma_mm": instrument_sigma_mm, "instrument_sigma_deg": instrument_sigma_deg,
                "registration": None if registration is None else list(registration),
                "drift": None if drift is None else list(drift),
                "outliers": None if outliers is None else list(outliers), "outlier_rows": outlier_rows,
                "repeatable_fraction": r, "settle_s": SETTLE_S, "slider_speed_mm_s": SLIDER_SPEED_MM_S,
                "rng": "root stream: order, directions, budget, noise; child_seed(seed, 1): per-pose draws; "
                       "child_seed(seed, 2): outliers",
                "budget": budget.name, "geometry": geometry.name, "version": __version__,
                "out_of_library": slider_error_fn is not None or pose_error_fn is not None,
                "plan": None if template is None else template.source}
    return Campaign.from_frame(frame, None, "simulated campaign", metadata)
