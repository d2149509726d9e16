"""Measurement campaigns (CSV, docs, *File formats*): reading with validation.

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

Simulated campaigns come from :mod:`~prp3mc.measurement.campaign.simulate`.
"""

from __future__ import annotations

import csv
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..._result import freeze, short_repr
from ...errors import CampaignError, InputFileError, Prp3mcWarning
from ...kinematics.chain import check_poses, feasible
from ...kinematics.geometry import Geometry
from ...model.effects import TEMP_LIMITS_C

__all__ = ["Campaign", "read_campaign", "REQUIRED_COLUMNS", "CMD_COLUMNS", "MEAS_COLUMNS", "DIR_COLUMNS",
           "MAX_ERROR", "MIN_POSES", "require_testable", "count_rows"]

#: Commanded and measured pose columns, ``[x mm, y mm, phi deg]``.
CMD_COLUMNS, MEAS_COLUMNS = ("x_cmd", "y_cmd", "phi_cmd"), ("x_meas", "y_meas", "phi_meas")
#: Columns every campaign needs.
REQUIRED_COLUMNS = ("pose_id", *CMD_COLUMNS, *MEAS_COLUMNS)
#: Optional approach-direction columns.
DIR_COLUMNS = ("dir_1", "dir_2", "dir_3")
#: Largest ``|measured - commanded|`` accepted (mm, mm, deg): beyond it a row is a unit, sign or column
#: mistake, which moves a pose by its coordinates (tens to hundreds of mm). A misassembled machine moves it by
#: a few mm: a base angle error of 3 deg on the delta-shape's leg 3 (a = 240 mm) by 7 mm, 10 deg of guide angle
#: on the U-shape by 13 mm (issue 24), which the discrepancy workflow follows on the exact chain.
MAX_ERROR = (25.0, 25.0, 10.0)
_SAME_CMD_TOL = 1e-6  # mm or deg: repeats of a pose must command the same pose
#: Fewest distinct poses a campaign must visit for the discrepancy workflow to test anything: one pose
#: is held out to cross-validate the others, and the instrument's registration (a pose-independent
#: rigid offset) takes 3 of the 3 per pose degrees of freedom, so two fitted poses are the least that leave any.
MIN_POSES = 3


@dataclass(frozen=True, slots=True)
class Campaign:
    """A validated measurement campaign (layout in the module docstring).

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
    metadata : mapping
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

    def __post_init__(self):
        freeze(self)

    def __repr__(self) -> str:
        return short_repr(self, "source", "n_measurements", "n_poses")

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
        """The campaign in the file layout (plus its extra columns): the file format, in mm and deg."""
        df = pd.DataFrame({"pose_id": self.pose_id})
        for k, col in enumerate(CMD_COLUMNS):
            df[col] = self.commanded[:, k]
        for k, col in enumerate(MEAS_COLUMNS):
            df[col] = self.measured[:, k]
        for k, col in enumerate(DIR_COLUMNS):
            if self.has_dir[k]:
                df[col] = self.direction[:, k].astype(int)
        if self.temp_C is not None:
            df["temp_C"] = self.temp_C
        return pd.concat([df, self.extra.reset_index(drop=True)], axis=1)

    def to_csv(self, path: str | os.PathLike) -> None:
        """Write the campaign as a campaign CSV file (full float precision)."""
        self.to_frame().to_csv(path, index=False, float_format="%.12g")

    @classmethod
    def from_frame(cls, frame: pd.DataFrame, geometry: Geometry | None = None,
                   source: str = "campaign", metadata: dict | None = None, line_offset: int | None = None) -> "Campaign":
        """Validate a table in the campaign layout.

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
        repeated = frame.duplicated().to_numpy()
        if "time_s" in frame.columns and repeated.any():   # the same time and readings twice: pasted, not measured
            warnings.warn(f"{where(np.flatnonzero(repeated), 'time_s')}: the same time and values as an earlier "
                          f"row ({int(repeated.sum())} such rows; a campaign pasted twice?): they count as "
                          "measurements", Prp3mcWarning, stacklevel=2)
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

        cmd = np.stack([numeric(c) for c in CMD_COLUMNS], axis=1)
        meas = np.stack([numeric(c) for c in MEAS_COLUMNS], axis=1)
        far = np.abs(meas - cmd) > np.array(MAX_ERROR)
        if far.any():
            r, k = (int(v) for v in np.argwhere(far)[0])
            raise CampaignError(f"{where(r, MEAS_COLUMNS[k])}: measured {meas[r, k]:g} is {abs(meas[r, k] - cmd[r, k]):g} "
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
        hot_or_cold = np.zeros(0) if temp is None else (temp < TEMP_LIMITS_C[0]) | (temp > TEMP_LIMITS_C[1])
        if hot_or_cold.any():
            r = int(np.flatnonzero(hot_or_cold)[0])
            raise CampaignError(f"{where(r, 'temp_C')}: {temp[r]:g} degrees C is outside the operating temperatures "
                                f"[{TEMP_LIMITS_C[0]:g}, {TEMP_LIMITS_C[1]:g}] (degrees C, not K or F?)")

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
            raise CampaignError(f"{where([r0, r], CMD_COLUMNS[k])}: pose_id {pose_id[r]!r} is commanded twice with "
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
        A CSV file with a header (the campaign layout), or a table in that layout.
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
    path = _campaign_file(data)
    _check_header(path)
    try:
        frame = pd.read_csv(path, dtype={"pose_id": str}, skipinitialspace=True, keep_default_na=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: not a readable CSV file ({str(exc).splitlines()[0]})") from None
    return Campaign.from_frame(frame, geometry, str(path), line_offset=1)


def _campaign_file(data: "str | os.PathLike") -> Path:
    path = Path(data)
    if not path.is_file():
        raise InputFileError(f"campaign file {path} does not exist")
    return path


def count_rows(data: "str | os.PathLike") -> int:
    """Data rows of a campaign CSV file (its lines after the header), counted without parsing it.

    What sizes an analysis before the file is read (blank lines count too);
    reads the file in blocks, so it needs no memory for a file of any size.

    Raises
    ------
    InputFileError
        The file is missing.
    """
    lines, last = 0, b"\n"
    with open(_campaign_file(data), "rb") as f:
        for block in iter(lambda: f.read(1 << 24), b""):
            lines, last = lines + block.count(b"\n"), block[-1:]
    return max(lines + (last != b"\n") - 1, 0)


def _check_header(path: Path) -> None:
    """Refuse a header that names a column twice (pandas would rename the second ``x_meas.1``)."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            header = next(csv.reader(f), [])
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputFileError(f"{path}: not a readable CSV file ({exc})") from None
    names = [name.strip() for name in header]
    for k, name in enumerate(names):
        if name and name in names[:k]:
            raise CampaignError(f"{path}: column {name!r} appears twice in the header (columns "
                                f"{names.index(name) + 1} and {k + 1}): which one holds the data is ambiguous")


def require_testable(campaign: Campaign) -> Campaign:
    """Refuse a campaign too small for the discrepancy workflow to test anything.

    It needs at least :data:`MIN_POSES` distinct poses and at least one pose
    measured twice (the dispersion channel compares repeats).

    Raises
    ------
    CampaignError
        One line saying what the campaign has and what it would need.
    """
    repeated = int(np.sum(campaign.repeats >= 2))
    if campaign.n_poses < MIN_POSES or repeated == 0:
        raise CampaignError(
            f"{campaign.source}: too small to test anything: {campaign.n_measurements} measurement(s) of "
            f"{campaign.n_poses} pose(s), {repeated} of them repeated; the discrepancy workflow needs at least "
            f"{MIN_POSES} distinct poses (one is held out, the registration takes 3 degrees of freedom) and at least "
            "one pose measured twice (the dispersion test compares repeats)")
    return campaign
