"""Simulated measurement campaigns with hidden effects, on the exact nonlinear chain.

:func:`simulate_campaign` makes campaigns with the exact nonlinear model,
fresh draws of the budget's random errors at every measurement, approach
directions, a temperature drift, instrument noise and hidden effects of the
library (:mod:`prp3mc.measurement.effects`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .._rng import resolve_rng
from .._version import __version__
from ..errors import CampaignError
from ..kinematics.chain import as_poses, check_poses, inverse_kinematics
from ..kinematics.exact import exact_pose_error
from ..kinematics.geometry import Geometry
from ..uncertainty.budget import Budget
from .campaign import CMD_COLUMNS, DIR_COLUMNS, MEAS_COLUMNS, Campaign
from .effects import effect, offset_errors, slider_error, spread_budget

__all__ = ["simulate_campaign"]


def simulate_campaign(geometry: Geometry, budget: Budget, poses, n_repeats: int = 8, *,
                      effects: dict | None = None, approach: str = "both",
                      temp_drift_C: tuple[float, float] | None = (20.0, 28.0),
                      instrument_sigma_mm: float = 0.002, instrument_sigma_deg: float = 0.0005,
                      slider_error_fn=None, pose_error_fn=None,
                      rng: "None | int | np.random.Generator" = None) -> Campaign:
    """Simulate a measurement campaign with the exact nonlinear model.

    The campaign visits every pose once per round, in a fresh random order
    each round, for ``n_repeats`` rounds; the temperature drifts linearly in
    time over the campaign. Every measurement draws fresh budget errors (a
    clearance settles at a new contact angle, an encoder reads a new count
    error each time the pose is approached) and fresh instrument noise.

    Parameters
    ----------
    geometry : Geometry
    budget : Budget
        Random errors; spread effects in ``effects`` change its laws.
    poses : array_like, shape (P, 3)
        Commanded poses ``[x_mm, y_mm, phi_deg]`` (any batch shape is flattened).
    n_repeats : int
        Measurements per pose.
    effects : dict of str to float, optional
        Hidden effects of the library (SPEC §5 names and units).
    approach : {"both", "positive", "negative", "sequence"}
        Approach direction of each actuator: random +-1 per actuator and
        measurement; always +1; always -1; or the sign of the actuator's
        move from the previous pose visited.
    temp_drift_C : (start, end) or None
        Temperature at the first and last measurement, degrees C; None for
        a campaign without a ``temp_C`` column (thermal effects then need it).
    instrument_sigma_mm, instrument_sigma_deg : float
        Standard deviation of the Gaussian measurement noise per coordinate.
    slider_error_fn, pose_error_fn : callable, optional
        Effects outside the library, for testing the workflow:
        ``f(commanded (M, 3), b (M, 3), direction (M, 3), temp_C (M,) or None)``
        returning an extra slider error delta b (M, 3) mm, or an extra pose
        error (M, 3) ``[mm, mm, deg]`` added to the exact one.
    rng : None, int or numpy.random.Generator
        Randomness (Scientific Python SPEC 7); the integer seed used is
        recorded in ``metadata["seed"]``, also when a Generator is given.

    Returns
    -------
    Campaign
        ``metadata`` records the seed, the hidden effects and the settings.
    """
    seed_used, rng = resolve_rng(rng)
    poses = as_poses(poses).reshape(-1, 3)
    check_poses(geometry, poses)
    n_repeats = int(n_repeats)
    if n_repeats < 1:
        raise CampaignError(f"n_repeats must be at least 1, got {n_repeats}")
    if approach not in ("both", "positive", "negative", "sequence"):
        raise CampaignError(f"approach must be both, positive, negative or sequence, got {approach!r}")
    effects = dict(effects or {})
    parsed = [effect(name) for name in effects]          # raises on unknown names
    if any(e.kind == "thermal" for e in parsed) and temp_drift_C is None:
        raise CampaignError("a hidden thermal effect needs a temperature drift (temp_drift_C)")
    for e, v in zip(parsed, effects.values()):
        if e.kind == "backlash" and v < 0:
            raise CampaignError(f"{e.name}: backlash h must be >= 0, got {v}")
    P = poses.shape[0]
    order = np.concatenate([rng.permutation(P) for _ in range(n_repeats)])   # visiting order
    M = order.size
    cmd = poses[order]
    b_pose, _ = inverse_kinematics(geometry, poses, check=False)
    b = b_pose[order]
    if approach == "both":
        direction = rng.choice([-1.0, 1.0], size=(M, 3))
    elif approach == "sequence":
        step = np.diff(b, axis=0, prepend=b[:1] - 1.0)
        direction = np.where(step > 0, 1.0, np.where(step < 0, -1.0, np.nan))
        direction = pd.DataFrame(direction).ffill().fillna(1.0).to_numpy()
    else:
        direction = np.full((M, 3), 1.0 if approach == "positive" else -1.0)
    temp = None if temp_drift_C is None else np.linspace(temp_drift_C[0], temp_drift_C[1], M)
    sim_budget = spread_budget(budget, effects)
    X = sim_budget.sample(M, rng)
    errors = sim_budget.errors(X)
    for family, value in offset_errors(effects).items():
        errors[family] = errors.get(family, 0.0) + value
    db = slider_error(effects, b, direction, temp)
    if slider_error_fn is not None:
        db = db + np.asarray(slider_error_fn(cmd, b, direction, temp), dtype=float)
    errors["b"] = errors.get("b", 0.0) + db
    err = exact_pose_error(geometry, cmd, errors, check=False)
    if pose_error_fn is not None:
        err = err + np.asarray(pose_error_fn(cmd, b, direction, temp), dtype=float)
    noise = rng.standard_normal((M, 3)) * np.array([instrument_sigma_mm, instrument_sigma_mm, instrument_sigma_deg])
    frame = pd.DataFrame({"pose_id": [f"P{k + 1:03d}" for k in order]})
    for k, col in enumerate(CMD_COLUMNS):
        frame[col] = cmd[:, k]
    for k, col in enumerate(MEAS_COLUMNS):
        frame[col] = cmd[:, k] + err[:, k] + noise[:, k]
    for k, col in enumerate(DIR_COLUMNS):
        frame[col] = direction[:, k].astype(int)
    if temp is not None:
        frame["temp_C"] = temp
    metadata = {"seed": seed_used, "effects": effects, "n_repeats": n_repeats, "approach": approach,
                "temp_drift_C": None if temp_drift_C is None else list(temp_drift_C),
                "instrument_sigma_mm": instrument_sigma_mm, "instrument_sigma_deg": instrument_sigma_deg,
                "budget": budget.name, "geometry": geometry.name, "version": __version__,
                "out_of_library": slider_error_fn is not None or pose_error_fn is not None}
    return Campaign.from_frame(frame, None, "simulated campaign", metadata)
