"""Measurement campaigns (CSV, docs, *File formats*): reading with validation.

A campaign is a table with one row per measurement: the commanded pose
``x_cmd, y_cmd, phi_cmd`` (mm, mm, deg), the measured pose ``x_meas, y_meas,
phi_meas``, a ``pose_id`` shared by the repeats of one commanded pose, and
optionally the approach direction ``dir_1, dir_2, dir_3`` (+-1) of each
actuator and the temperature ``temp_C``. Other columns are kept and ignored.

Repeats are optional. A campaign that visits every pose once (a laser
tracker's sweep) is enough for the systematic channels of the discrepancy
workflow; repeats buy its dispersion channels (spreads, the repeatable
fraction, the repeat scatter), which compare the visits of a pose. The
workflow needs at least :data:`MIN_POSES` distinct poses
(:func:`require_testable`).

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
import re
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from ..._result import freeze, short_repr
from ...errors import CampaignError, InputFileError, Prp3mcWarning
from ...kinematics.chain import check_poses, feasible
from ...kinematics.geometry import Geometry
from ...model.effects import TEMP_LIMITS_C
from ...model.linear import linear_model

__all__ = ["Campaign", "read_campaign", "REQUIRED_COLUMNS", "CMD_COLUMNS", "MEAS_COLUMNS", "DIR_COLUMNS",
           "MAX_ERROR", "MIN_POSES", "require_testable", "count_rows", "CAMPAIGN_PRESETS", "check_error_scale",
           "check_instrument_noise"]

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
#: Bundled campaigns, by name (``--data example``; how each was made: the script beside it).
CAMPAIGN_PRESETS = {"example": "data/campaigns/example.csv"}
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
        self.to_frame().to_csv(path, index=False)   # shortest repr of each float: reads back exactly

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
                shown = "empty" if pd.isna(raw.iloc[r]) or not str(raw.iloc[r]).strip() else f"{raw.iloc[r]!r}"
                raise CampaignError(f"{where(r, column)}: expected a finite number, got {shown}"
                                    + (f" ({int(bad.sum())} such rows)" if bad.sum() > 1 else ""))
            return values

        if all((frame[c].isna() | (frame[c].astype(str).str.strip() == "")).all() for c in MEAS_COLUMNS):
            raise CampaignError(f"{source}: every {', '.join(MEAS_COLUMNS)} cell is empty: an unmeasured plan "
                                "template (prp3mc plan)? Measure each row and fill in the measured columns, or "
                                "try it on a simulated campaign: prp3mc simulate --plan FILE.csv")
        cmd = np.stack([numeric(c) for c in CMD_COLUMNS], axis=1)
        meas = np.stack([numeric(c) for c in MEAS_COLUMNS], axis=1)
        _check_units(cmd, meas, source)
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
        if temp is not None and _KELVIN[0] <= temp.min() and temp.max() <= _KELVIN[1]:
            raise CampaignError(f"{where(int(np.argmin(temp)), 'temp_C')}: every temperature lies in "
                                f"[{temp.min():g}, {temp.max():g}], {temp.min() - 273.15:.4g} to "
                                f"{temp.max() - 273.15:.4g} degrees C if in kelvin: temp_C must be in degrees C "
                                "(subtract 273.15)")
        if temp is not None and _FAHRENHEIT[0] <= temp.min() and temp.max() <= _FAHRENHEIT[1]:
            warnings.warn(f"{source}: every temp_C lies in [{temp.min():g}, {temp.max():g}] degrees C, hotter than "
                          f"any room machines are measured in: if they are degrees F ({(temp.min() - 32) / 1.8:.4g} "
                          f"to {(temp.max() - 32) / 1.8:.4g} degrees C), convert them (C = (F - 32) / 1.8)",
                          Prp3mcWarning, stacklevel=2)
        if "time_s" in frame.columns:
            frame = frame.assign(time_s=_seconds(frame["time_s"], where))
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
                reason += _unit_hint(geometry, poses)
                rows = np.flatnonzero(index == p)
                raise CampaignError(f"{where(rows[0], 'x_cmd, y_cmd, phi_cmd')}: pose_id {labels[order][p]!r}: "
                                    f"{reason} (geometry {geometry.name})")
        extra = frame.drop(columns=[c for c in frame.columns
                                    if c in REQUIRED_COLUMNS or c in DIR_COLUMNS or c == "temp_C"])
        return cls(pose_id=pose_id, commanded=cmd, measured=meas, direction=direction, has_dir=has_dir,
                   temp_C=temp, extra=extra.reset_index(drop=True), poses=poses,
                   pose_labels=tuple(str(v) for v in labels[order]), pose_index=index,
                   source=source, metadata=dict(metadata or {}))


#: Temperatures that are plausible machine-room temperatures in kelvin (-50 to 100 degrees C) and
#: implausible in degrees C (above 220): such a temp_C column is refused as kelvin.
_KELVIN = (223.15, 373.15)
#: Temperatures of machine rooms in degrees F (10 to 40 degrees C) that are 50 degrees C and more as degrees C:
#: legal (an oven test), so such a temp_C column is run with a warning naming Fahrenheit, not refused.
_FAHRENHEIT = (50.0, 104.0)
#: Factors of the usual unit mistakes, (measured / commanded, what it means).
_UNIT_FACTORS = ((1 / 25.4, "inches (measured / commanded = 1/25.4)"), (25.4, "mm against a command in inches"),
                 (1000.0, "µm (measured / commanded = 1000)"), (1e-3, "metres (measured / commanded = 1/1000)"))
_ANGLE_FACTORS = ((np.pi / 180, "radians (measured / commanded = pi/180)"),
                  (180 / np.pi, "degrees against a command in radians"))


def _check_units(cmd: np.ndarray, meas: np.ndarray, source: str) -> None:
    """Refuse measured columns whose ratio to the command is a unit factor (inch, µm, m, rad), naming it.

    Only rows far enough from zero to show a ratio count (1 mm, 0.5 deg);
    the median ratio must match the factor within 2 %, which no error of a
    machine comes near.
    """
    for k, (factors, least) in enumerate(((_UNIT_FACTORS, 1.0), (_UNIT_FACTORS, 1.0), (_ANGLE_FACTORS, 0.5))):
        big = np.abs(cmd[:, k]) > least
        if big.sum() < max(3, big.size // 2):
            continue
        ratio = float(np.median(meas[big, k] / cmd[big, k]))
        for factor, unit in factors:
            if abs(ratio / factor - 1) < 0.02:
                what = "deg" if k == 2 else "mm"
                raise CampaignError(f"{source}: column {MEAS_COLUMNS[k]} looks like {unit}: measured poses must be "
                                    f"in mm and deg, like the command (convert {MEAS_COLUMNS[k]} to {what})")


#: Level of the test that refuses an instrument noise the campaign's scatter rules out.
INSTRUMENT_NOISE_LEVEL = 1e-6


def check_instrument_noise(campaign: "Campaign", sigma_mm: float, sigma_deg: float) -> None:
    """Refuse an instrument noise that the campaign's own scatter rules out (a µm or arcsec figure given in mm or deg).

    The instrument's noise adds to every other scatter of the measured errors
    (measured - commanded): their variance about their mean is at least
    sigma². With nu degrees of freedom, ``nu s² / sigma²`` is then at least
    chi²(nu) distributed, and a value below its :data:`INSTRUMENT_NOISE_LEVEL`
    quantile rules the stated sigma out (x and y pooled, phi on its own).

    Parameters
    ----------
    campaign : Campaign
    sigma_mm, sigma_deg : float
        Stated instrument noise sd of x and y (mm) and of phi (deg); 0 is not checked.

    Raises
    ------
    CampaignError
        One line: the stated sd, the campaign's scatter, the largest sd it allows, the likely unit.
    """
    from scipy.stats import chi2

    errors = campaign.measured - campaign.commanded
    for columns, sigma, option, unit, small, factor in (((0, 1), sigma_mm, "--instrument-sigma-mm", "mm", "µm", 1e3),
                                                         ((2,), sigma_deg, "--instrument-sigma-deg", "deg", "arcsec",
                                                          3600.0)):
        e = errors[:, columns]
        nu = e.size - len(columns)
        if not sigma > 0 or nu < 2:
            continue
        s2 = float(np.sum((e - e.mean(axis=0)) ** 2)) / nu
        least = float(chi2.ppf(INSTRUMENT_NOISE_LEVEL, nu))
        if sigma > np.sqrt(nu * s2 / least):                 # sigma ** 2 would overflow for a huge sigma
            raise CampaignError(f"{option} {sigma:g}: the campaign's measured errors scatter by {s2 ** 0.5:.3g} {unit} "
                                f"(sd over {e.shape[0]} rows) and instrument noise only adds to that, so its sd is at "
                                f"most {(nu * s2 / least) ** 0.5:.3g} {unit}: give it in {unit} (if {sigma:g} is in "
                                f"{small}: {sigma / factor:g} {unit})")


def _unit_hint(geometry: Geometry, poses: np.ndarray) -> str:
    """A hint when the commanded poses are unreachable but would all be reached in another length unit."""
    for factor, unit in ((25.4, "inches"), (1000.0, "metres"), (1e-3, "µm")):
        if feasible(geometry, poses * np.array([factor, factor, 1.0])).all():
            return f"; every commanded pose is reachable if x_cmd, y_cmd are in {unit}: the campaign must be in mm"
    return ""


def _seconds(column: pd.Series, where) -> np.ndarray:
    """``time_s`` as seconds: numbers as they are, ISO 8601 timestamps as seconds since the earliest.

    Raises
    ------
    CampaignError
        A row without a time (empty, ``-``, ``NA``), a time that is neither a
        finite number nor a timestamp, or numbers and timestamps mixed.
    """
    missing = column.isna() | (column.astype(str).str.strip() == "")
    if missing.any():
        rows = np.flatnonzero(missing.to_numpy())
        raise CampaignError(f"{where(rows, 'time_s')}: no time ({len(rows)} such rows): give every measurement its "
                            "time, or drop the column (row order then stands for time)")
    numbers = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float)
    if np.isfinite(numbers).all():
        return numbers
    text = column.astype(str).str.strip()
    stamps = pd.to_datetime(text, errors="coerce", utc=True, format="ISO8601")
    if stamps.notna().all():
        return (stamps - stamps.min()).dt.total_seconds().to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(numbers) & stamps.isna().to_numpy())
    r = int(bad[0]) if bad.size else int(np.flatnonzero(~np.isfinite(numbers))[0])
    raise CampaignError(f"{where(r, 'time_s')}: expected seconds (a finite number) or an ISO 8601 timestamp such as "
                        f"2026-03-01T08:00:00, got {column.iloc[r]!r}"
                        + ("; the column mixes numbers and timestamps" if bad.size == 0 else ""))


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
    header, sep, decimal = _check_header(path)
    # pose_id is a label: "NA", "none" or "null" name a pose (pandas would read them as missing)
    missing = {name: list(_MISSING) for name in header if name.strip() != "pose_id"}
    try:
        frame = pd.read_csv(path, sep=sep, decimal=decimal, dtype={"pose_id": str}, skipinitialspace=True,
                            keep_default_na=False, na_values=missing, encoding="utf-8-sig")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        raise InputFileError(f"{_shown(path)}: not a readable CSV file ({str(exc).splitlines()[0]})") from None
    return Campaign.from_frame(frame, geometry, _shown(path), line_offset=1)


#: Cells read as missing in the numeric columns (pandas' defaults; pose_id keeps them as labels).
_MISSING = ("", "#N/A", "#N/A N/A", "#NA", "-1.#IND", "-1.#QNAN", "-NaN", "-nan", "1.#IND", "1.#QNAN", "<NA>", "N/A",
            "NA", "NULL", "NaN", "None", "n/a", "nan", "null", "none", "-")


def _shown(path: Path) -> str:
    """``path`` as text that can be printed whatever its bytes (a name that is not UTF-8 shows escapes)."""
    return os.fsdecode(path).encode("utf-8", "backslashreplace").decode("utf-8")


def _campaign_file(data: "str | os.PathLike") -> Path:
    """The file ``data`` names: a path, or a bundled campaign's name (:data:`CAMPAIGN_PRESETS`) if no such file exists."""
    path = Path(data)
    if not path.is_file() and str(data) in CAMPAIGN_PRESETS:
        path = Path(str(resources.files("prp3mc").joinpath(CAMPAIGN_PRESETS[str(data)])))
    if not path.is_file():
        raise InputFileError(f"campaign file {_shown(path)} does not exist"
                             + (f" (bundled: {', '.join(CAMPAIGN_PRESETS)})" if path.suffix != ".csv" else ""))
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


def _check_header(path: Path) -> tuple[list[str], str, str]:
    """The header's column names, the delimiter and the decimal mark of a campaign file.

    A UTF-8 byte-order mark is skipped; the delimiter is sniffed among
    comma, semicolon and tab (a spreadsheet's export), and a semicolon file
    whose numbers have decimal commas is read so. Refuses a header that
    names a column twice (pandas would rename the second ``x_meas.1``).
    """
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            head = f.read(1 << 16)
    except UnicodeDecodeError as exc:
        raise InputFileError(f"{_shown(path)}: not a readable CSV file: not UTF-8 text ({exc.reason} at byte "
                             f"{exc.start}); save it as UTF-8") from None
    lines = head.splitlines()
    sep = ","
    if lines and "," not in lines[0]:
        try:
            sep = csv.Sniffer().sniff("\n".join(lines[:20]), delimiters=",;\t").delimiter
        except csv.Error:
            sep = ","
    try:
        header = next(csv.reader(lines[:1], delimiter=sep), [])
    except csv.Error as exc:
        raise InputFileError(f"{_shown(path)}: not a readable CSV file ({exc})") from None
    # decimal commas: a semicolon or tab file whose cells look like 1,5 (no cell of a comma file can)
    decimal = "," if sep != "," and any(re.search(r"(^|[;\t])-?\d+,\d+([;\t]|$)", line) for line in lines[1:20]) else "."
    names = [name.strip() for name in header]
    for k, name in enumerate(names):
        if name and name in names[:k]:
            raise CampaignError(f"{_shown(path)}: column {name!r} appears twice in the header (columns "
                                f"{names.index(name) + 1} and {k + 1}): which one holds the data is ambiguous")
    return names, sep, decimal


def check_error_scale(campaign: Campaign, geometry: Geometry, budget, instrument_sigma_mm: float = 0.0) -> None:
    """Refuse a campaign written wholly in inches (commands and measurements), naming the unit.

    Such a campaign passes every per-row check: its poses are reachable
    (near the base) and its errors small. Two signs together give it away:
    every commanded pose is reachable at 25.4 times its coordinates, and
    the position errors scatter (about their mean) less than a tenth of
    what the budget and the instrument predict (an inch campaign: 1/25.4).

    Raises
    ------
    CampaignError
        One line naming inches and the scatter ratio.
    """
    scaled = campaign.poses * np.array([25.4, 25.4, 1.0])
    if not feasible(geometry, scaled).all():
        return
    _, cov = linear_model(geometry, budget, campaign.poses, check=False).moments()
    predicted = float(np.mean(cov[:, 0, 0] + cov[:, 1, 1])) + 2 * instrument_sigma_mm ** 2
    centred = campaign.error[:, :2] - campaign.error[:, :2].mean(axis=0)
    ratio = np.sqrt(np.mean(np.sum(centred ** 2, axis=1)) / predicted) if predicted > 0 else np.inf
    if 0 < ratio < 0.1:
        raise CampaignError(f"{campaign.source}: the campaign looks like inches: every commanded pose is reachable "
                            f"at 25.4 times its x, y, and the position errors scatter {ratio:.3g} times what the budget "
                            "predicts (1/25.4 = 0.039 in inches): commands and measurements must be in mm")


def require_testable(campaign: Campaign) -> Campaign:
    """Refuse a campaign too small for the discrepancy workflow to test anything.

    It needs at least :data:`MIN_POSES` distinct poses. A campaign that
    measures no pose twice is accepted: its systematic channels are tested,
    its dispersion channels (which compare repeats) are not.

    Raises
    ------
    CampaignError
        One line saying what the campaign has and what it would need.
    """
    if campaign.n_poses < MIN_POSES:
        raise CampaignError(
            f"{campaign.source}: too small to test anything: {campaign.n_measurements} measurement(s) of "
            f"{campaign.n_poses} pose(s); the discrepancy workflow needs at least {MIN_POSES} distinct poses (one is "
            "held out, the registration takes 3 degrees of freedom)")
    return campaign
