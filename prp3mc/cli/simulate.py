"""``prp3mc simulate``: a measurement campaign of a machine with hidden effects, on the exact chain."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from . import (add_budget, add_geometry, add_instrument_noise, add_json, add_seed, command, emit_json,
               nonnegative_float, positive_int, provenance, within_limits)
from ..errors import CampaignError, InputFileError
from ..limits import simulate_estimate
from ..output import OutputExistsError
from ..provenance import file_record


def _pairs(text: str) -> dict[str, float]:
    """``'scale_2=5e-4,backlash_1=0.02'`` as ``{name: value}`` (names are checked by the simulation)."""
    out = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, sep, value = item.partition("=")
        try:
            number = float(value) if sep else math.nan
        except ValueError:
            number = math.nan
        if not name.strip() or not math.isfinite(number):
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE pairs separated by commas "
                                             f"(e.g. scale_2=5e-4,backlash_1=0.02), got {item!r}")
        if name.strip() in out:
            raise argparse.ArgumentTypeError(f"{name.strip()} is given twice: give each effect once")
        out[name.strip()] = number
    return out


def _numbers(text: str, option: str, count: tuple[int, ...], what: str) -> tuple[float, ...]:
    """``'a,b,c'`` as finite floats, as many as ``count`` allows."""
    try:
        values = tuple(float(t) for t in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in count or not all(map(math.isfinite, values)):
        raise CampaignError(f"{option}: expected {what}, got {text!r}")
    return values


def spread_poses(region, n: int) -> np.ndarray:
    """``n`` poses over a region, row by row: ``ceil(sqrt(n))`` per full row, the last row spread over x.

    Parameters
    ----------
    region : Region
    n : int
        Number of poses, >= 1.

    Returns
    -------
    ndarray, shape (n, 3)
        ``[x_mm, y_mm, phi_deg]``; a square number gives the region's n-point grid.
    """
    per_row = math.ceil(math.sqrt(n))
    rows = math.ceil(n / per_row)
    y = np.linspace(*region.y_mm, rows) if rows > 1 else np.array([np.mean(region.y_mm)])
    counts = [per_row] * (rows - 1) + [n - per_row * (rows - 1)]
    xs = [np.linspace(*region.x_mm, c) if c > 1 else np.array([np.mean(region.x_mm)]) for c in counts]
    x = np.concatenate(xs)
    return np.stack([x, np.repeat(y, counts), np.full(n, region.phi_deg)], axis=1)


def _read_plan(args, path: str):
    """The campaign template at ``path`` as a table (validated by the simulation), its size checked before it
    is read (rows counted without parsing)."""
    import pandas as pd

    from ..measurement.campaign.data import count_rows

    if not Path(path).is_file():
        raise InputFileError(f"campaign plan {path} does not exist")
    within_limits(args, simulate_estimate(count_rows(path)))
    try:
        return pd.read_csv(path, dtype={"pose_id": str}, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: not a readable CSV file ({str(exc).splitlines()[0]})") from None


@command("simulate", "simulate a measurement campaign (CSV) of a machine with hidden effects")
class SimulateCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        where = p.add_mutually_exclusive_group(required=True)
        where.add_argument("--poses", type=positive_int, metavar="N",
                           help="visit N poses spread over --region (a square N is its N-point grid)")
        where.add_argument("--plan", metavar="FILE.csv",
                           help="a campaign template (the campaign columns, measured ones empty): its rows in "
                                "order, with their dir_1..dir_3 and time_s when given")
        p.add_argument("--region", default=None, metavar="R",
                       help="where --poses lie: a preset or a region TOML file (default: the geometry preset's)")
        p.add_argument("--visits", type=positive_int, default=8, metavar="V",
                       help="visits of every pose, each round in a fresh random order (default 8; not with --plan)")
        p.add_argument("--effects", type=_pairs, default={}, metavar="NAME=V,...",
                       help="hidden effects in their units (mm, deg, 1, 1/K), e.g. 'scale_2=5e-4,backlash_1=0.02'")
        p.add_argument("--registration", default=None, metavar="DX,DY,DEG",
                       help="the instrument's frame error: mm, mm, deg (default: registered)")
        p.add_argument("--drift", default=None, metavar="DX,DY,DEG",
                       help="instrument drift from first to last measurement: mm, mm, deg (default none)")
        p.add_argument("--outliers", default=None, metavar="F[,SIZE]",
                       help="fraction F of measurements with a gross position error of SIZE mm (default 0.5)")
        p.add_argument("--repeatable-fraction", type=nonnegative_float, default=0.0, metavar="R",
                       help="share of the budget's variance that repeats at a pose's revisits (default 0)")
        p.add_argument("--approach", choices=("both", "positive", "negative", "sequence"), default="both",
                       help="approach direction of each actuator (default both: random)")
        p.add_argument("--temperature", default="20,28", metavar="START,END",
                       help="temperature at the first and last measurement, deg C (default 20,28; 'none' for "
                            "no temp_C column)")
        add_instrument_noise(p, 0.002, 0.0005)
        add_seed(p)
        p.add_argument("--out", dest="out_file", required=True, metavar="CAMPAIGN.csv",
                       help="the campaign file to write ('-': stdout)")
        p.add_argument("--force", action="store_true", help="replace CAMPAIGN.csv if it exists")
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..kinematics.geometry import GEOMETRY_PRESETS, Geometry, Region
        from ..measurement.campaign.simulate import check_plausible, simulate_campaign
        from ..model.budget import Budget

        if not args.out_file.strip():
            raise CampaignError("--out is empty: name the campaign file to write (or '-' for stdout)")
        out = None if args.out_file == "-" else Path(args.out_file)
        if out is not None and out.suffix.lower() not in ("", ".csv"):
            raise CampaignError(f"--out {out}: the campaign is a CSV file; name it CAMPAIGN.csv (or '-' for stdout)")
        check_plausible(args.effects, args.instrument_sigma_mm, args.instrument_sigma_deg,
                        labels=("--effects", "--instrument-sigma-mm", "--instrument-sigma-deg"))
        if out is None and args.json:
            raise CampaignError("--json prints to stdout: write the campaign to a file (--out CAMPAIGN.csv)")
        if out is not None and out.exists() and not args.force:
            raise OutputExistsError(f"{out} exists: choose another name or pass --force to replace it")
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        settings = {
            "registration": None if args.registration is None else _numbers(
                args.registration, "--registration", (3,), "DX,DY,DEG (mm, mm, deg)"),
            "drift": None if args.drift is None else _numbers(args.drift, "--drift", (3,), "DX,DY,DEG (mm, mm, deg)"),
            "outliers": None if args.outliers is None else (_numbers(
                args.outliers, "--outliers", (1, 2), "F or F,SIZE_MM") + (0.5,))[:2],
            "temp_drift_C": None if args.temperature.strip().lower() == "none" else _numbers(
                args.temperature, "--temperature", (2,), "START,END (deg C) or none"),
        }
        if args.plan is not None:
            plan, poses, where = _read_plan(args, args.plan), None, {"plan": file_record(args.plan)}
        else:
            within_limits(args, simulate_estimate(args.poses * args.visits))
            region_spec = args.region or (args.geometry if args.geometry in GEOMETRY_PRESETS else None)
            if region_spec is None:
                raise CampaignError("--poses needs --region (a preset or a region file) for a geometry file")
            plan, poses = None, spread_poses(Region.load(region_spec), args.poses)
            where = {"region": region_spec, "n_poses": args.poses, "visits": args.visits}
        campaign = simulate_campaign(
            geometry, budget, poses, args.visits, effects=args.effects, approach=args.approach,
            instrument_sigma_mm=args.instrument_sigma_mm, instrument_sigma_deg=args.instrument_sigma_deg,
            repeatable_fraction=args.repeatable_fraction, rng=args.seed, plan=plan, **settings)
        frame = campaign.to_frame()
        if out is None:
            frame.to_csv(sys.stdout, index=False, float_format="%.12g", lineterminator="\n")
        else:
            from ..output import write_text

            out.parent.mkdir(parents=True, exist_ok=True)
            write_text(out, frame.to_csv(index=False, float_format="%.12g", lineterminator="\n"))
        meta = campaign.metadata
        if args.json:
            emit_json({"file": None if out is None else str(out), "n_measurements": campaign.n_measurements,
                       "n_poses": campaign.n_poses, "outlier_rows": meta["outlier_rows"],
                       **provenance(args, geometry, budget, seed=meta["seed"], effects=args.effects, **where,
                                    **{k: v for k, v in settings.items() if v is not None})})
        elif out is not None:
            print(f"wrote {out}: {campaign.n_measurements} measurements of {campaign.n_poses} poses, seed "
                  f"{meta['seed']}" + (f", hidden {', '.join(f'{k}={v:g}' for k, v in args.effects.items())}"
                                       if args.effects else ""))
