"""Measurement campaigns (SPEC §4): reading with validation, and a simulator.

A campaign is a table with one row per measurement: the commanded pose
``x_cmd, y_cmd, phi_cmd`` (mm, mm, deg), the measured pose ``x_meas, y_meas,
phi_meas``, a ``pose_id`` shared by the repeats of one commanded pose, and
optionally the approach direction ``dir_1, dir_2, dir_3`` (+-1) of each
actuator and the temperature ``temp_C``. Other columns are kept and ignored.

Reading refuses, with the row and the column in the message, anything it
would otherwise have to guess: missing columns, empty or non-numeric cells,
repeats of one ``pose_id`` with different commands, directions other than
+-1, commanded poses the manipulator cannot reach, and measured poses so far
from the command that they must be a unit mistake.

:func:`simulate_campaign` makes campaigns with the exact nonlinear model,
fresh draws of the budget's random errors at every measurement, approach
directions, a temperature drift, instrument noise and hidden effects of the
library (:mod:`prp3mc.measurement.effects`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .._rng import resolve_rng
from .._version import __version__
from ..uncertainty.budget import Budget
from .effects import effect, offset_errors, slider_error, spread_budget
from ..errors import CampaignError, InputFileError
from ..kinematics.exact import exact_pose_error
from ..kinematics.geometry import Geometry
from ..kinematics.chain import as_poses, check_poses, feasible, inverse_kinematics

__all__ = ["Campaign", "read_campaign", "simulate_campaign", "REQUIRED_COLUMNS", "MAX_ERROR"]

#: Columns every campaign needs (SPEC §4).
REQUIRED_COLUMNS = ("pose_id", "x_cmd", "y_cmd", "phi_cmd", "x_meas", "y_meas", "phi_meas")
DIR_COLUMNS = ("dir_1", "dir_2", "dir_3")
#: Largest |measured - commanded| accepted (mm, mm, deg): beyond it a row is a unit or sign mistake.
MAX_ERROR = (5.0, 5.0, 5.0)
_CMD, _MEAS = ["x_cmd", "y_cmd", "phi_cmd"], ["x_meas", "y_meas", "phi_meas"]
_SAME_CMD_TOL = 1e-6  # mm or deg: repeats of a pose must command the same pose


@dataclass(frozen=True, slots=True)
class Campaign:
    """A validated measurement campaign (SPEC §4).

    Attributes
    ----------
    pose_id : ndarray of str, shape (M,)
        Label of each measurement's commanded pose.
    commanded, measured : ndarray, shape (M, 3)
        ``[x_mm, y_mm, phi_deg]``.
    direction : ndarray, shape (M, 3)
        Approach direction +-1 of each actuator; 0 where the column is absent.
    has_dir : tuple of 3 bool
        Which ``dir_i`` columns the campaign has.
    temp_C : ndarray, shape (M,) or None
        Temperature at each measurement, degrees C.
    extra : DataFrame
        Other columns, kept and ignored.
    poses : ndarray, shape (P, 3)
        Distinct commanded poses, in order of first appearance.
    pose_labels : tuple of str, length P
    pose_index : ndarray of int, shape (M,)
        Index into ``poses`` of each measurement.
    source : str
    metadata : dict
        For simulated campaigns: seed, hidden effects, settings, version.
    """

    pose_id: np.ndarray
    commanded: np.ndarray
    measured: np.ndarray
    direction: np.ndarray
    has_dir: tuple
    temp_C: np.ndarray | None
    extra: pd.DataFrame
    poses: np.ndarray
    pose_labels: tuple
    pose_index: np.ndarray
    source: str = "campaign"
    metadata: dict = field(default_factory=dict)

    @property
    def n_measurements(self) -> int:
        return int(self.pose_id.shape[0])

    @property
    def n_poses(self) -> int:
        return int(self.poses.shape[0])

    @property
    def repeats(self) -> np.ndarray:
        """Number of measurements of each pose, shape (P,)."""
        return np.bincount(self.pose_index, minlength=self.n_poses)

    @property
    def error(self) -> np.ndarray:
        """Measured minus commanded pose, shape (M, 3): dx mm, dy mm, dphi deg."""
        return self.measured - self.commanded

    def to_frame(self) -> pd.DataFrame:
        """The campaign in SPEC §4 layout (plus its extra columns)."""
        df = pd.DataFrame({"pose_id": self.pose_id})
        for k, col in enumerate(_CMD):
            df[col] = self.commanded[:, k]
        for k, col in enumerate(_MEAS):
            df[col] = self.measured[:, k]
        for k, col in enumerate(DIR_COLUMNS):
            if self.has_dir[k]:
                df[col] = self.direction[:, k].astype(int)
        if self.temp_C is not None:
            df["temp_C"] = self.temp_C
        return pd.concat([df, self.extra.reset_index(drop=True)], axis=1)

    def to_csv(self, path: str | os.PathLike) -> None:
        """Write the campaign as a SPEC §4 CSV file (full float precision)."""
        self.to_frame().to_csv(path, index=False, float_format="%.12g")

    @classmethod
    def from_frame(cls, frame: pd.DataFrame, geometry: Geometry | None = None,
                   source: str = "campaign", metadata: dict | None = None, line_offset: int | None = None) -> "Campaign":
        """Validate a table in SPEC §4 layout.

        Parameters
        ----------
        frame : DataFrame
            One row per measurement.
        geometry : Geometry, optional
            If given, every commanded pose must be reachable.
        source : str
            Name used in error messages.
        line_offset : int, optional
            If the table came from a file, data row ``r`` (1-based) is on
            line ``r + line_offset``; messages then give the line too.

        Raises
        ------
        CampaignError
            Naming the row(s) and column of the first problem found.
        """
        def where(rows, column) -> str:
            rows = [int(r) for r in np.atleast_1d(rows)]
            text = ", ".join(str(r + 1) for r in rows[:5]) + (" ..." if len(rows) > 5 else "")
            lines = ""
            if line_offset is not None:
                lines = " (line" + ("s " if len(rows) > 1 else " ") + ", ".join(
                    str(r + 1 + line_offset) for r in rows[:5]) + ")"
            return f"{source}: row{'s' if len(rows) > 1 else ''} {text}{lines}, column {column}"

        frame = frame.rename(columns=lambda c: str(c).strip())
        dup = frame.columns[frame.columns.duplicated()].tolist()
        if dup:
            raise CampaignError(f"{source}: column(s) {', '.join(dup)} appear more than once in the header")
        missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
        if missing:
            raise CampaignError(f"{source}: missing required column(s) {', '.join(missing)} "
                                f"(a campaign needs {', '.join(REQUIRED_COLUMNS)})")
        if len(frame) == 0:
            raise CampaignError(f"{source}: the campaign has no rows")
        ids = frame["pose_id"]
        blank = ids.isna() | (ids.astype(str).str.strip() == "")
        if blank.any():
            raise CampaignError(f"{where(np.flatnonzero(blank.to_numpy()), 'pose_id')}: empty pose_id")
        pose_id = ids.astype(str).str.strip().to_numpy()

        def numeric(column: str) -> np.ndarray:
            raw = frame[column]
            values = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float)
            bad = ~np.isfinite(values)
            if bad.any():
                r = int(np.flatnonzero(bad)[0])
                shown = "empty" if pd.isna(raw.iloc[r]) else f"{raw.iloc[r]!r}"
                raise CampaignError(f"{where(r, column)}: expected a finite number, got {shown}"
                                    + (f" ({int(bad.sum())} such rows)" if bad.sum() > 1 else ""))
            return values

        cmd = np.stack([numeric(c) for c in _CMD], axis=1)
        meas = np.stack([numeric(c) for c in _MEAS], axis=1)
        far = np.abs(meas - cmd) > np.array(MAX_ERROR)
        if far.any():
            r, k = (int(v) for v in np.argwhere(far)[0])
            raise CampaignError(f"{where(r, _MEAS[k])}: measured {meas[r, k]:g} is {abs(meas[r, k] - cmd[r, k]):g} "
                                f"{'deg' if k == 2 else 'mm'} from the commanded {cmd[r, k]:g} (more than "
                                f"{MAX_ERROR[k]:g}): check units (mm, deg) and columns")
        has_dir = tuple(c in frame.columns for c in DIR_COLUMNS)
        direction = np.zeros((len(frame), 3))
        for k, c in enumerate(DIR_COLUMNS):
            if has_dir[k]:
                d = numeric(c)
                bad = ~np.isin(d, (-1.0, 1.0))
                if bad.any():
                    r = int(np.flatnonzero(bad)[0])
                    raise CampaignError(f"{where(r, c)}: an approach direction must be +1 or -1, got {d[r]:g}")
                direction[:, k] = d
        temp = numeric("temp_C") if "temp_C" in frame.columns else None

        labels, first, index = np.unique(pose_id, return_index=True, return_inverse=True)
        order = np.argsort(first)                        # poses in order of first appearance
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        index = rank[index.ravel()]
        poses = cmd[first[order]]
        diff = np.abs(cmd - poses[index]) > _SAME_CMD_TOL * (1.0 + np.abs(poses[index]))
        if diff.any():
            r, k = (int(v) for v in np.argwhere(diff)[0])
            r0 = int(first[order][index[r]])
            raise CampaignError(f"{where([r0, r], _CMD[k])}: pose_id {pose_id[r]!r} is commanded twice with "
                                f"different values ({cmd[r0, k]:g} and {cmd[r, k]:g}); "
                                "repeats of a pose must command the same pose")
        if geometry is not None:
            ok = feasible(geometry, poses)
            if not ok.all():
                p = int(np.flatnonzero(~ok)[0])
                try:
                    check_poses(geometry, poses[p])
                    reason = "is not reachable"
                except Exception as exc:  # noqa: BLE001 -- its message is the reason
                    reason = str(exc)
                rows = np.flatnonzero(index == p)
                raise CampaignError(f"{where(rows[0], 'x_cmd, y_cmd, phi_cmd')}: pose_id {labels[order][p]!r}: "
                                    f"{reason} (geometry {geometry.name})")
        extra = frame.drop(columns=[c for c in frame.columns
                                    if c in REQUIRED_COLUMNS or c in DIR_COLUMNS or c == "temp_C"])
        return cls(pose_id=pose_id, commanded=cmd, measured=meas, direction=direction, has_dir=has_dir,
                   temp_C=temp, extra=extra.reset_index(drop=True), poses=poses,
                   pose_labels=tuple(str(v) for v in labels[order]), pose_index=index,
                   source=source, metadata=dict(metadata or {}))


def read_campaign(data: "str | os.PathLike | pd.DataFrame | Campaign", geometry: Geometry | None = None) -> Campaign:
    """Read and validate a campaign from a CSV file, a DataFrame or a Campaign.

    Parameters
    ----------
    data : path, DataFrame or Campaign
        A CSV file with a header (SPEC §4), or a table in that layout.
    geometry : Geometry, optional
        If given, every commanded pose must be reachable by it.

    Raises
    ------
    InputFileError
        The file is missing or not CSV.
    CampaignError
        The campaign is malformed; the message names row and column.
    """
    if isinstance(data, Campaign):
        return data if geometry is None else Campaign.from_frame(data.to_frame(), geometry, data.source,
                                                                 data.metadata)
    if isinstance(data, pd.DataFrame):
        return Campaign.from_frame(data, geometry, "campaign")
    path = Path(data)
    if not path.is_file():
        raise InputFileError(f"campaign file {path} does not exist")
    try:
        frame = pd.read_csv(path, dtype={"pose_id": str}, skipinitialspace=True, keep_default_na=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: not a readable CSV file ({str(exc).splitlines()[0]})") from None
    return Campaign.from_frame(frame, geometry, str(path), line_offset=1)


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
    for k, col in enumerate(_CMD):
        frame[col] = cmd[:, k]
    for k, col in enumerate(_MEAS):
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
