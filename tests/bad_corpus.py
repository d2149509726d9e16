"""A corpus of bad and odd inputs to every command (issue 25), judged by what a user would see.

Each :class:`Case` is a command line (``{name}`` stands for a prepared file
of :func:`prepare`, ``{tmp}`` for the corpus folder), the class it belongs
to, and what must happen: a refusal (non-zero exit, one line on stderr naming
the fragment, nothing written) or an accepted run (exit 0, and the case's own
check of what it wrote). ``tests/test_bad_input.py`` runs the cases in
process; run this module to run every case in a real ``python -m prp3mc``
process with a timeout and count, by class, the cases that end badly::

    PYTHONPATH=. python -m tests.bad_corpus [--only CLASS] [--jobs N]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

#: The classes of issue 25, in the order of the closing note.
CLASSES = ("tracebacks", "hangs", "signals", "row order", "read-back", "messages", "silently accepted",
           "leftovers & permissions")

G, B, P = ["--geometry", "u-shape"], ["--budget", "paper"], ["--pose", "0", "100", "0"]
D = ["discrepancy", *G, *B]
HEADER = "pose_id,x_cmd,y_cmd,phi_cmd,x_meas,y_meas,phi_meas"


@dataclass
class Case:
    """One corpus entry; see the module docstring."""

    cls: str
    argv: list
    expect: str = "refuse"            # or "accept"
    message: str = ""                 # fragment of the refusal's one line
    status: tuple = (1,)
    check: Callable | None = None     # (root) -> problem text or None, after an accepted run
    slow: bool = False                # an accepted analysis (seconds): in process only in the slow run
    setup: Callable | None = None     # (root) -> None: what the folder holds before the run
    left: str = ""                    # why this case still ends badly (counted so, an expected failure in tests)
    process: bool = False             # run in a real process in the tests too (its stdout takes any file name)
    warning: str = ""                 # an accepted run must warn with this fragment (a legal but unlikely input)
    id: str = field(default="")

    def __post_init__(self):
        if not self.id:
            self.id = " ".join(str(a) for a in self.argv)[:90]


def _geometry_text(name: str = "g", legs=None) -> str:
    """A geometry TOML: the U-shape's legs with some keys changed (``legs``: three dicts of overrides)."""
    base = [dict(a_mm=140.0, alpha_deg=180.0, beta_deg=-90.0, gamma_deg=-90.0, theta_deg=0.0, c_mm=40.0, e_mm=10.0,
                 psi_deg=180.0, stroke_mm=[0.0, 200.0]),
            dict(a_mm=140.0, alpha_deg=0.0, beta_deg=90.0, gamma_deg=90.0, theta_deg=0.0, c_mm=40.0, e_mm=10.0,
                 psi_deg=0.0, stroke_mm=[0.0, 200.0]),
            dict(a_mm=180.0, alpha_deg=90.0, beta_deg=-90.0, gamma_deg=-90.0, theta_deg=0.0, c_mm=40.0, e_mm=10.0,
                 psi_deg=90.0, stroke_mm=[-100.0, 100.0])]
    for leg, change in zip(base, legs or ({}, {}, {})):
        leg.update(change)
    out = f"name = {json.dumps(name)}\n"
    for leg in base:
        out += "[[leg]]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in leg.items())
    return out


PAPER = "".join(f'theta_{i} = {{ law = "uniform", lo = -0.04, hi = 0.04 }}\n'
                f'b_{i} = {{ law = "uniform", lo = -0.005, hi = 0.005 }}\n' for i in (1, 2, 3))


def _budget_text(name: str = "b", inputs: str = PAPER, extra: str = "") -> str:
    return f"name = {json.dumps(name)}\n{extra}[inputs]\n{inputs}"


def _campaign(root: Path, drift=None, repeats: int = 3, seed: int = 1, perfect: bool = False):
    """A small simulated campaign of the U-shape (9 poses), as a DataFrame."""
    from prp3mc import Budget, Geometry
    from prp3mc.kinematics.geometry import Region
    from prp3mc.measurement.campaign.simulate import simulate_campaign
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    c = simulate_campaign(g, b, Region.from_preset("u-shape").grid(3), n_repeats=repeats, rng=seed, drift=drift)
    frame = c.to_frame()
    if perfect:
        for a, m in zip(("x_cmd", "y_cmd", "phi_cmd"), ("x_meas", "y_meas", "phi_meas")):
            frame[m] = frame[a]
    return frame


def _csv(frame, **kw) -> str:
    return frame.to_csv(index=False, float_format="%.12g", **kw)


def prepare(root: Path) -> dict:
    """Write every input file of the corpus under ``root``; return name -> path (str, or bytes for odd names)."""
    import numpy as np
    root.mkdir(parents=True, exist_ok=True)
    good = _campaign(root)
    drifted = _campaign(root, drift=(0.03, 0.0, 0.0), repeats=4, seed=2)
    files: dict[str, str | bytes] = {
        # singular geometries
        "g_parallel": _geometry_text("parallel", ({}, {}, {"beta_deg": 0.0, "theta_deg": 180.0})),
        "g_identical": _geometry_text("identical", ({},) + (dict(a_mm=140.0, alpha_deg=180.0, beta_deg=-90.0,
                                                                  gamma_deg=-90.0, psi_deg=180.0,
                                                                  stroke_mm=[0.0, 200.0]),) * 2),
        "g_guide_parallel": _geometry_text("guide", ({"theta_deg": 90.0}, {}, {})),
        "g_guide_parallel_3": _geometry_text("guide3", ({}, {}, {"theta_deg": 90.0})),
        "g_zero_legs": _geometry_text("zero", ({"c_mm": 0.0, "e_mm": 0.0}, {"c_mm": 0.0, "e_mm": 0.0},
                                               {"c_mm": 0.0, "e_mm": 0.0})),
        # names that must read back
        "g_ctrl_name": _geometry_text("bad\x01name\ttab"),
        "g_unicode_name": _geometry_text("Gerät µ — ☃"),
        "b_ctrl_name": _budget_text("b\x07ell\x1f"),
        "b_unicode_group": _budget_text("b", extra='[groups]\n"Führung ☃" = ["theta_1", "theta_2"]\n"ctl\\u0001" = ["b_1"]\n'),
        # TOML with a BOM
        "g_bom": "\ufeff" + _geometry_text(),
        "b_bom": "\ufeff" + _budget_text(),
        "b_correlated": _budget_text(extra="[correlation]\n\"theta_1,theta_2\" = 0.5\n"),
        # one leg random: no 2-D density, so no exact yield (known only by trying): prp3mc yield's Monte Carlo
        "b_no_density": _budget_text(inputs='rho_1 = { law = "disc", radius = 0.01 }\n'
                                            'zeta_1 = { law = "uniform", lo = 0, hi = 360 }\n'),
        "s_bom": "\ufeff" + 'name = "s"\nseed = 1\n[worstcase]\ngrid = 3\n[[configuration]]\ngeometry = "u-shape"\n',
        "classes_bom": "\ufeff" + 'name = "c"\n[theta]\nclasses = [{ name = "x", catalogue = "guide_angular_play.paper", cost = 1.0 }]\n',
        # budgets silently accepted
        "b_discrete_overflow": _budget_text(inputs="".join(
            f'theta_{i} = {{ law = "discrete", values = [-0.01, 0.03], weights = [1e308, 1e308] }}\n' for i in (1, 2, 3))),
        "b_discrete_tiny": _budget_text(inputs="".join(
            f'theta_{i} = {{ law = "discrete", values = [-0.01, 0.03], weights = [1e-320, 1e-320] }}\n' for i in (1, 2, 3))),
        "b_discrete_neg": _budget_text(inputs="".join(
            f'theta_{i} = {{ law = "discrete", values = [-0.01, 0.03], weights = [2, -1] }}\n' for i in (1, 2, 3))),
        "b_discrete_zero": _budget_text(inputs="".join(
            f'theta_{i} = {{ law = "discrete", values = [-0.01, 0.03], weights = [0, 0] }}\n' for i in (1, 2, 3))),
        "b_overlap_groups": _budget_text(extra='[groups]\ng1 = ["theta_1", "theta_2"]\ng2 = ["theta_2", "b_1"]\n'),
        "b_same_groups": _budget_text(extra='[groups]\ng1 = ["theta_1", "theta_2"]\ng2 = ["theta_2", "theta_1"]\n'),
        "b_clearance_group": _budget_text("b", PAPER + "".join(
            f'rho_{i} = {{ law = "uniform", lo = 0, hi = 0.005 }}\nzeta_{i} = {{ law = "uniform", lo = 0, hi = 360 }}\n'
            for i in (1, 2, 3)), extra='[groups]\nclearance_1 = ["theta_1"]\n'),
        "b_group_dup": _budget_text(extra='[groups]\ng1 = ["theta_1", "theta_1"]\n'),
        "b_group_is_input": _budget_text(extra='[groups]\nb_2 = ["theta_1"]\n'),
        "b_huge_sd": _budget_text(inputs="".join(f'theta_{i} = {{ law = "normal", mu = 0, sd = 1e154 }}\n' for i in (1, 2, 3))),
        # campaigns
        "c_good": _csv(good),
        "c_perfect": _csv(_campaign(root, perfect=True)),
        "c_perfect_notime": _csv(_campaign(root, perfect=True).drop(columns=["time_s"])),
        "c_semicolon": _csv(good, sep=";"),
        "c_semicolon_decimal": _csv(good, sep=";", decimal=","),
        "c_tab": _csv(good, sep="\t"),
        "c_bom": "\ufeff" + _csv(good),
        "c_pose_na": _csv(good.assign(pose_id=np.where(good["pose_id"] == good["pose_id"].iloc[0], "NA",
                                                       good["pose_id"]))),
        "c_pose_none": _csv(good.assign(pose_id=np.where(good["pose_id"] == good["pose_id"].iloc[0], "none",
                                                         good["pose_id"]))),
        "c_pose_null": _csv(good.assign(pose_id=np.where(good["pose_id"] == good["pose_id"].iloc[0], "null",
                                                         good["pose_id"]))),
        "c_time_iso": _csv(good.assign(time_s=(np.datetime64("2026-03-01T08:00:00")
                                               + good["time_s"].to_numpy().astype("timedelta64[s]")).astype(str))),
        "c_time_iso_tz": _csv(good.assign(time_s=[f"2026-03-01T08:{int(t) // 60:02d}:{int(t) % 60:02d}+01:00"
                                                  for t in good["time_s"]])),
        "c_time_dash": _csv(good.assign(time_s=["-" if k == 3 else str(t) for k, t in enumerate(good["time_s"])])),
        "c_time_empty": _csv(good.assign(time_s=["" if k == 3 else str(t) for k, t in enumerate(good["time_s"])])),
        "c_time_text": _csv(good.assign(time_s=["soon" if k == 3 else str(t) for k, t in enumerate(good["time_s"])])),
        "c_time_inf": _csv(good.assign(time_s=[np.inf if k == 3 else t for k, t in enumerate(good["time_s"])])),
        "c_time_mixed": _csv(good.assign(time_s=["2026-03-01T08:00:00" if k == 0 else str(t)
                                                 for k, t in enumerate(good["time_s"])])),
        "c_drift": _csv(drifted),
        "c_drift_reversed": _csv(drifted.iloc[::-1]),
        "c_drift_iso_reversed": _csv(drifted.assign(time_s=(np.datetime64("2026-03-01T08:00:00") + drifted[
            "time_s"].to_numpy().astype("timedelta64[s]")).astype(str)).iloc[::-1]),
        "c_drift_shuffled": _csv(drifted.sample(frac=1.0, random_state=3)),
        "c_inch": _csv(good.assign(**{c: good[c] / 25.4 for c in ("x_meas", "y_meas")})),
        "c_inch_all": _csv(good.assign(**{c: good[c] / 25.4 for c in ("x_meas", "y_meas", "x_cmd", "y_cmd")})),
        "c_um": _csv(good.assign(**{c: good[c] * 1000 for c in ("x_meas", "y_meas")})),
        "c_rad": _csv(good.assign(phi_cmd=5.0, phi_meas=np.deg2rad(5.0 + good["phi_meas"] - good["phi_cmd"]))),
        "c_kelvin": _csv(good.assign(temp_C=good["temp_C"] + 273.15)),
        "c_fahrenheit": _csv(good.assign(temp_C=good["temp_C"] * 9 / 5 + 32)),
        "c_huge_values": _csv(good.assign(x_cmd=1e300, x_meas=1e300)),
        "c_crlf": _csv(good).replace("\n", "\r\n"),
        "c_quoted": _csv(good, quoting=1),
        "c_latin1": _csv(good.assign(note="Gerät")).encode("latin-1"),
        "c_trailing_comma": _csv(good).replace("\n", ",\n"),
        "c_blank_lines": _csv(good).replace("\n", "\n\n"),
        # studies
        "s_ok": 'name = "s"\nseed = 1\n[worstcase]\ngrid = 3\n[[configuration]]\ngeometry = "u-shape"\n',
        # every section of a study's report (worst case, Monte Carlo, Sobol) at sizes of seconds: the signal loop's
        "s_signal": ('name = "sig"\nseed = 1\noutputs = ["montecarlo", "sobol"]\n[worstcase]\ngrid = 5\n'
                     '[montecarlo]\nsamples = 4096\ngrid = 3\n[sobol]\nsamples = 256\ngrid = 2\n'
                     '[[configuration]]\ngeometry = "u-shape"\nregion = "u-shape"\n'),
        "s_parallel": 'name = "s"\nseed = 1\n[worstcase]\ngrid = 3\n[[configuration]]\ngeometry = "{g_parallel}"\n'
                      'region = "u-shape"\n',
        "s_multiply": ('name = "s"\nseed = 1\n[worstcase]\ngrid = 601\n[montecarlo]\nsamples = 1048576\ngrid = 41\n'
                       '[sobol]\nsamples = 65536\ngrid = 21\n[[configuration]]\ngeometry = "u-shape"\n'
                       '[sweep]\n"leg.3.a_mm" = [170, 175, 180, 185, 190, 195, 200, 205]\n'),
        "s_sweep_sizes": ('name = "s"\nseed = 1\n[montecarlo]\nsamples = 262144\ngrid = 21\n[[configuration]]\n'
                          'geometry = "u-shape"\n[sweep]\n"leg.3.a_mm" = [' + ", ".join(str(170 + k) for k in range(40))
                          + ']\n"leg.1.c_mm" = [38, 40, 42, 44]\n'),
        # a sweep of 1000 configurations of small grids: their histograms' draws (48 GB) are what will not fit
        "s_sweep_histograms": ('name = "s"\nseed = 1\noutputs = ["montecarlo"]\n[worstcase]\ngrid = 3\n[montecarlo]\n'
                               'samples = 1000000\ngrid = 2\n[[configuration]]\ngeometry = "u-shape"\n'
                               'region = "u-shape"\n[sweep]\n"leg.3.a_mm" = ['
                               + ", ".join(f"{200 + k / 100:g}" for k in range(1000)) + ']\n'),
        "s_allocation_big": None,   # filled below (needs the classes file's path)
        "s_sweep_delta_model": None,
        "s_ctrl_name": 'name = "s\\u0001x"\nseed = 1\n[worstcase]\ngrid = 3\n[[configuration]]\ngeometry = "u-shape"\n',
    }
    # regions, budgets in the wrong unit, a campaign template (the second corpus)
    region = 'x_mm = [-40.0, 40.0]\ny_mm = [60.0, 140.0]\n'
    files.update({
        "r_reversed": 'x_mm = [40.0, -40.0]\ny_mm = [60.0, 140.0]\n',
        "r_zero": 'x_mm = [0.0, 0.0]\ny_mm = [100.0, 100.0]\n',
        "r_far": 'x_mm = [-400.0, 400.0]\ny_mm = [600.0, 1400.0]\n',
        "r_nan": 'x_mm = [nan, 1.0]\ny_mm = [60.0, 140.0]\n',
        "r_missing_y": 'x_mm = [-40.0, 40.0]\n',
        "r_unknown": region + 'z_mm = [0, 1]\n',
        "r_string": 'x_mm = "wide"\ny_mm = [60.0, 140.0]\n',
        "r_phi_string": region + 'phi_deg = "level"\n',
        "r_phi_bool": region + 'phi_deg = true\n',
        "r_bom": "\ufeff" + region,
        "r_empty": "",
        "r_three": 'x_mm = [-40.0, 0.0, 40.0]\ny_mm = [60.0, 140.0]\n',
        "r_table": 'x_mm = { lo = -40, hi = 40 }\ny_mm = [60.0, 140.0]\n',
        "r_int": 'x_mm = [-40, 40]\ny_mm = [60, 140]\n',
        "r_inf": 'x_mm = [-inf, 40.0]\ny_mm = [60.0, 140.0]\n',
        "b_mm_for_um": _budget_text(inputs="".join(f'b_{i} = {{ law = "uniform", lo = -2.5, hi = 2.5 }}\n'
                                                   for i in (1, 2, 3))),
        "b_arcsec_for_deg": _budget_text(inputs="".join(f'theta_{i} = {{ law = "uniform", lo = -144, hi = 144 }}\n'
                                                        for i in (1, 2, 3))),
        "b_sd_mm_for_um": _budget_text(inputs="".join(f'b_{i} = {{ law = "normal", mu = 0, sd = 5 }}\n'
                                                      for i in (1, 2, 3))),
        "c_plan": _csv(good.drop(columns=["x_meas", "y_meas", "phi_meas"])),
        "c_plan_far": _csv(good.drop(columns=["x_meas", "y_meas", "phi_meas"]).assign(y_cmd=400.0)),
        "c_template": _csv(good.assign(x_meas=None, y_meas=None, phi_meas=None)),   # as prp3mc plan writes it
        "c_one_empty": _csv(good.assign(phi_meas=None)),
        "s_formats": 'name = "f"\nseed = 1\noutputs = ["montecarlo"]\n[worstcase]\ngrid = 3\n[montecarlo]\n'
                     'samples = 1024\ngrid = 2\n[[configuration]]\ngeometry = "u-shape"\nregion = "u-shape"\n',
        "s_region_file": None,   # filled below (needs the region file's path)
        "s_region_reversed": None,
    })
    # nine families of six classes each: 6^9 = 10 million choices
    families = ("rho", "theta", "b", "a", "alpha", "beta", "c", "gamma", "psi")
    big = 'name = "big"\n'
    for f in families:
        big += f"[{f}]\nclasses = [\n" + "".join(
            f'  {{ name = "k{k}", law = "uniform", lo = {0.0 if f == "rho" else -(k + 1) * 0.001}, '
            f'hi = {(k + 1) * 0.001}, cost = {6 - k}.0 }},\n' for k in range(6)) + "]\n"
    files["classes_big"] = big
    from prp3mc import Budget, Geometry
    from prp3mc._toml import dumps_toml
    from prp3mc.model.effects import SystematicEffect
    files["b_u_model"] = dumps_toml(Budget.from_preset("paper").with_effects(
        {"backlash_1": SystematicEffect("backlash_1", 0.02, campaign="c1.csv")},
        fitted_on=Geometry.from_preset("u-shape")).to_dict())
    files["b_delta_model"] = dumps_toml(Budget.from_preset("paper").with_effects(
        {"backlash_1": SystematicEffect("backlash_1", 0.02, campaign="c1.csv")},
        fitted_on=Geometry.from_preset("delta-shape")).to_dict())
    paths: dict[str, str | bytes] = {}
    ext = {"g": "toml", "b": "toml", "s": "toml", "c": "csv", "classes": "toml", "r": "toml"}
    for name in files:
        paths[name] = str(root / f"{name}.{ext.get(name.split('_')[0], 'toml')}")
    files["s_allocation_big"] = ('name = "s"\nseed = 1\n[allocation]\nclasses = "' + paths["classes_big"]
                                 + '"\nspec_position_um = 30\ngrid = 5\n[[configuration]]\ngeometry = "u-shape"\n')
    files["s_sweep_delta_model"] = ('name = "s"\nseed = 1\nbudget = "' + paths["b_u_model"] + '"\n[worstcase]\n'
                                    'grid = 3\n[[configuration]]\ngeometry = "u-shape"\n[sweep]\n'
                                    '"leg.3.a_mm" = [170, 180]\n')
    files["s_parallel"] = files["s_parallel"].replace("{g_parallel}", paths["g_parallel"])
    files["s_region_file"] = ('name = "s"\nseed = 1\n[worstcase]\ngrid = 3\n[[configuration]]\ngeometry = "u-shape"\n'
                              f'region = {json.dumps(paths["r_reversed"])}\n')   # a study takes presets or tables
    files["s_region_reversed"] = ('name = "s"\nseed = 1\n[worstcase]\ngrid = 3\n[[configuration]]\n'
                                  'geometry = "u-shape"\nregion = { x_mm = [40, -40], y_mm = [60, 140] }\n')
    for name, content in files.items():
        data = content if isinstance(content, bytes) else content.encode("utf-8")
        Path(paths[name]).write_bytes(data)
    # a data file and an output folder whose names are not UTF-8
    odd = os.fsencode(str(root)) + b"/caf\xe9.csv"
    with open(odd, "wb") as f:
        f.write(files["c_good"].encode())
    paths["c_nonutf8"] = odd
    paths["g_nonutf8"] = os.fsencode(str(root)) + b"/g\xff.toml"
    with open(paths["g_nonutf8"], "wb") as f:
        f.write(_geometry_text().encode())
    paths["out_nonutf8"] = b"out\xe9"   # relative: the run's own folder
    # a dangling symlink, a symlink to an earlier output, a read-only folder
    dangling = root / "dangling"
    if not dangling.is_symlink():
        dangling.symlink_to(root / "nowhere")
    paths["dangling"] = str(dangling)
    paths["root"] = str(root)
    return paths


def _reads_back(folder: str, *names: str) -> Callable:
    """Check: every ``model/*.toml`` under ``folder`` is read by prp3mc as geometry or budget."""
    def check(root: Path) -> str | None:
        from prp3mc import Budget, Geometry
        for name in names:
            path = root / folder / name
            if not path.exists():
                return f"{path} was not written"
            try:
                (Geometry if "geometry" in name else Budget).from_toml(path)
            except Exception as exc:  # noqa: BLE001
                return f"{path} does not read back: {exc}"
        return None
    return check


def _mode_ok(folder: str) -> Callable:
    def check(root: Path) -> str | None:
        mode = (root / folder).stat().st_mode & 0o777
        umask = os.umask(0)
        os.umask(umask)
        want = 0o777 & ~umask
        return None if mode == want else f"{folder} has mode {oct(mode)}, the umask gives {oct(want)}"
    return check


def _drift_of(folder: str, at_least_mm: float = 0.015) -> Callable:
    def check(root: Path) -> str | None:
        doc = json.loads((root / folder / "discrepancy.json").read_text())
        drift = [n for n in doc["nuisance"] if n["name"] == "drift_x"]
        if not drift or drift[0]["value"] < at_least_mm:
            return f"{folder}: drift_x {drift[0]['value'] if drift else 'not named'}, the campaign drifts 0.03 mm"
        return None
    return check


def _wrote(folder: str, name: str = "discrepancy.json") -> Callable:
    def check(root: Path) -> str | None:
        return None if (root / folder / name).is_file() else f"{folder}/{name} missing"
    return check


def cases() -> list[Case]:
    """The corpus (every case's files come from :func:`prepare`)."""
    out: list[Case] = []
    add = out.append
    T = "tracebacks"
    # ------------------------------------------------------------------ singular geometries, every command
    for g, msg in (("{g_parallel}", "singular"), ("{g_identical}", "singular"), ("{g_guide_parallel}", "leg 1"),
                   ("{g_guide_parallel_3}", "leg 3")):
        add(Case(T, ["sensitivity", "--geometry", g, *P], message=msg))
        add(Case(T, ["worstcase", "--geometry", g, *B, *P], message=msg))
        add(Case(T, ["montecarlo", "--geometry", g, *B, *P, "--samples", "1024", "--seed", "1"], message=msg))
        add(Case(T, ["sobol", "--geometry", g, *B, *P, "--samples", "256", "--seed", "1"], message=msg))
        add(Case(T, ["allocate", "--geometry", g, "--region", "u-shape", "--classes", "example",
                     "--spec-position-um", "150", "--grid", "3"], message=msg))
    add(Case(T, ["worstcase", "--geometry", "{g_zero_legs}", *B, *P, "--json"], expect="accept"))  # legitimate
    add(Case(T, ["study", "{s_parallel}", "--out", "{tmp}/s_parallel"], message="singular"))
    add(Case(T, ["discrepancy", "--geometry", "{g_parallel}", *B, "--data", "{c_good}", "--out", "{tmp}/d_par"],
             message="singular"))
    for pose in (["0", "100", "90"], ["0", "100", "-90"], ["0", "100", "89.9999"], ["0", "100", "270"]):
        add(Case(T, ["worstcase", *G, *B, "--pose", *pose], message="leg"))
        add(Case(T, ["sensitivity", *G, "--pose", *pose], message="leg"))
    # ------------------------------------------------------------------ perfect and odd-but-legal campaigns
    add(Case(T, [*D, "--data", "{c_perfect}", "--out", "{tmp}/d_perfect", "--seed", "1"], expect="accept",
             check=_wrote("d_perfect"), slow=True))
    add(Case(T, [*D, "--data", "{c_perfect_notime}", "--out", "{tmp}/d_perfect2", "--seed", "1", "--no-registration"],
             expect="accept", check=_wrote("d_perfect2"), slow=True))
    add(Case(T, [*D, "--data", "{c_good}", "--out", "{tmp}/d_sig", "--seed", "1", "--instrument-sigma-mm", "1e300"],
             message="instrument"))
    add(Case(T, [*D, "--data", "{c_good}", "--out", "{tmp}/d_sig2", "--seed", "1", "--instrument-sigma-deg", "1e200"],
             message="instrument"))
    add(Case(T, [*D, "--data", "{c_good}", "--out", "{tmp}/d_sig3", "--seed", "1", "--instrument-sigma-mm", "1e-300"],
             expect="accept", check=_wrote("d_sig3"), slow=True))
    add(Case(T, ["worstcase", *G, "--budget", "{b_huge_sd}", *P], message="beyond any error"))
    add(Case(T, [*D, "--data", "{c_time_iso}", "--out", "{tmp}/d_iso", "--seed", "1"], expect="accept",
             check=_wrote("d_iso"), slow=True))
    add(Case(T, [*D, "--data", "{c_time_iso_tz}", "--out", "{tmp}/d_isotz", "--seed", "1"], expect="accept",
             check=_wrote("d_isotz"), slow=True))
    add(Case(T, [*D, "--data", "{c_time_dash}", "--out", "{tmp}/d_dash"], message="time_s"))
    add(Case(T, [*D, "--data", "{c_time_empty}", "--out", "{tmp}/d_tempty"], message="time_s"))
    add(Case(T, [*D, "--data", "{c_time_text}", "--out", "{tmp}/d_ttext"], message="time_s"))
    add(Case(T, [*D, "--data", "{c_time_inf}", "--out", "{tmp}/d_tinf"], message="time_s"))
    add(Case(T, [*D, "--data", "{c_time_mixed}", "--out", "{tmp}/d_tmixed"], message="time_s"))
    add(Case(T, [*D, "--data", "{c_huge_values}", "--out", "{tmp}/d_huge"], message="x_cmd"))
    add(Case(T, ["study", "quick", "--out", ""], message="--out"))
    add(Case(T, ["study", "quick", "--out", " "], message="--out"))
    add(Case(T, ["init", "budget", "/"], message="/"))
    add(Case(T, ["init", "budget", "{tmp}"], message="exists"))
    add(Case(T, ["init", "budget", "{c_nonutf8}"], message="exists"))
    for out_dir in ("/", "//", "/.", "."):
        add(Case(T, ["study", "quick", "--out", out_dir], message="--out"))
        add(Case(T, [*D, "--data", "{c_good}", "--out", out_dir], message="--out"))
    add(Case(T, ["study", "quick", "--out", "/", "--force"], message="--out"))
    add(Case(T, ["study", "quick", "--out", "{tmp}/.."], message="--out"))
    add(Case(T, [*D, "--data", "{c_nonutf8}", "--out", "{tmp}/d_nonutf8", "--seed", "1"], expect="accept",
             check=_wrote("d_nonutf8"), slow=True))
    add(Case(T, ["sensitivity", "--geometry", "{g_nonutf8}", *P, "--json"], expect="accept"))
    add(Case(T, ["worstcase", "--geometry", "{g_nonutf8}", *B, *P, "--json"], expect="accept"))
    add(Case(T, ["study", "{s_ok}", "--out", "{out_nonutf8}"], expect="accept", slow=True, process=True,
             check=lambda root: None if any(n.startswith(b"out") for n in os.listdir(os.fsencode(str(root))))
             else "the folder was not written"))
    for spec in ("ucx://127.0.0.1:8786", "tls://127.0.0.1:8786", "inproc://x", "ws://127.0.0.1:1", "wss://h:1",
                 "tcp://", "tcp://:", "local:0", "local:-1", "local:abc", "http://127.0.0.1:8786", "local:1e3"):
        add(Case(T, ["study", "{s_ok}", "--out", "{tmp}/sched", "--scheduler", spec], message="--scheduler"))
    # ------------------------------------------------------------------ hangs
    H = "hangs"
    add(Case(H, ["--max-hours", "0.002", "study", "{s_allocation_big}", "--out", "{tmp}/h0"], message="--max-hours",
             slow=True))
    add(Case(H, ["--max-hours", "0.005", "allocate", *G, "--region", "u-shape", "--classes", "{classes_big}",
                 "--spec-position-um", "30", "--grid", "5"], message="--max-hours", slow=True))
    add(Case(H, ["--max-hours", "0.005", "allocate", *G, "--region", "u-shape", "--classes", "{classes_big}",
                 "--spec-position-um", "30", "--grid", "5", "--front"], message="--max-hours", slow=True))
    add(Case(H, ["--max-hours", "0.005", "study", "{s_allocation_big}", "--out", "{tmp}/h1"], message="--max-hours",
             slow=True))
    add(Case(H, ["--max-hours", "0.005", "study", "{s_multiply}", "--out", "{tmp}/h2"], message="--max-hours",
             slow=True))
    add(Case(H, ["--max-hours", "0.005", "study", "{s_sweep_sizes}", "--out", "{tmp}/h3"], message="--max-hours",
             slow=True))
    add(Case(H, ["--max-gb", "0.01", "study", "{s_multiply}", "--out", "{tmp}/h4"], message="GiB"))
    add(Case(H, ["--max-gb", "0.0001", "montecarlo", *G, *B, *P, "--samples", "1048576"], message="--max-gb"))
    add(Case(H, ["--max-hours", "0.0001", "sobol", *G, *B, *P, "--samples", "65536"], message="--max-hours"))
    add(Case(H, ["--max-gb", "0", "sensitivity", *G, *P], status=(2,), message="> 0"))
    add(Case(H, ["--max-gb", "nan", "sensitivity", *G, *P], status=(2,), message="finite"))
    # ------------------------------------------------------------------ row order
    R = "row order"
    add(Case(R, [*D, "--data", "{c_drift}", "--out", "{tmp}/r1", "--seed", "1"], expect="accept",
             check=_drift_of("r1"), slow=True))
    add(Case(R, [*D, "--data", "{c_drift_reversed}", "--out", "{tmp}/r2", "--seed", "1"], expect="accept",
             check=_drift_of("r2"), slow=True))
    add(Case(R, [*D, "--data", "{c_drift_iso_reversed}", "--out", "{tmp}/r4", "--seed", "1"], expect="accept",
             check=_drift_of("r4"), slow=True))
    add(Case(R, [*D, "--data", "{c_drift_shuffled}", "--out", "{tmp}/r3", "--seed", "1"], expect="accept",
             check=_drift_of("r3"), slow=True))
    # ------------------------------------------------------------------ read-back
    RB = "read-back"
    add(Case(RB, ["discrepancy", "--geometry", "{g_ctrl_name}", "--budget", "{b_ctrl_name}", "--data", "{c_good}",
                  "--out", "{tmp}/rb1", "--seed", "1"], expect="accept", slow=True,
             check=_reads_back("rb1/model", "geometry.toml", "budget.toml", "budget_compensated.toml")))
    add(Case(RB, ["discrepancy", "--geometry", "{g_unicode_name}", "--budget", "{b_unicode_group}", "--data",
                  "{c_good}", "--out", "{tmp}/rb2", "--seed", "1"], expect="accept", slow=True,
             check=_reads_back("rb2/model", "geometry.toml", "budget.toml", "budget_compensated.toml")))
    add(Case(RB, ["worstcase", "--geometry", "{g_ctrl_name}", "--budget", "{b_ctrl_name}", *P, "--json"],
             expect="accept"))
    add(Case(RB, ["sobol", *G, "--budget", "{b_unicode_group}", *P, "--samples", "256", "--seed", "1", "--json"],
             expect="accept"))
    add(Case(RB, ["study", "{s_ctrl_name}", "--out", "{tmp}/rb3"], message="control characters"))  # names files
    add(Case(RB, ["sobol", *G, "--budget", "{b_ctrl_name}", *P, "--samples", "256", "--seed", "1", "--json"],
             expect="accept"))
    add(Case("messages", ["montecarlo", *G, "--budget", "{b_bom}", *P, "--samples", "1024", "--seed", "1", "--json"],
             expect="accept"))
    add(Case(T, ["study", "{s_ok}", "--out", "{tmp}/sched", "--scheduler", "tcp://127.0.0.1:99999"],
             message="--scheduler"))
    for kind in ("geometry", "budget", "study", "classes"):
        add(Case(RB, ["init", kind, f"{{tmp}}/init_{kind}.toml"], expect="accept",
                 check=lambda root, kind=kind: _init_reads(root / f"init_{kind}.toml", kind)))
    # ------------------------------------------------------------------ messages
    M = "messages"
    add(Case(M, ["sensitivity", "--geometry", "{g_guide_parallel}", *P], message="parallel"))
    add(Case(M, ["worstcase", "--geometry", "{g_guide_parallel}", *B, *P], message="parallel"))
    add(Case(M, ["sensitivity", *G, "--pose", "0", "100", "90"], message="parallel"))
    add(Case(M, ["sensitivity", "--geometry", "{g_bom}", *P, "--json"], expect="accept"))
    add(Case(M, ["worstcase", *G, "--budget", "{b_bom}", *P, "--json"], expect="accept"))
    add(Case(M, ["study", "{s_bom}", "--out", "{tmp}/m_sbom"], expect="accept", slow=True))
    add(Case(M, ["allocate", *G, "--region", "u-shape", "--classes", "{classes_bom}", "--spec-position-um", "1000",
                 "--grid", "3", "--json"], expect="accept"))
    add(Case(M, [*D, "--data", "{c_bom}", "--out", "{tmp}/m_cbom", "--seed", "1"], expect="accept", slow=True,
             check=_wrote("m_cbom")))
    add(Case(M, [*D, "--data", "{c_semicolon}", "--out", "{tmp}/m_semi", "--seed", "1"], expect="accept", slow=True,
             check=_wrote("m_semi")))
    add(Case(M, [*D, "--data", "{c_semicolon_decimal}", "--out", "{tmp}/m_semi2", "--seed", "1"], expect="accept",
             slow=True, check=_wrote("m_semi2")))
    add(Case(M, [*D, "--data", "{c_tab}", "--out", "{tmp}/m_tab", "--seed", "1"], expect="accept", slow=True,
             check=_wrote("m_tab")))
    for name in ("c_pose_na", "c_pose_none", "c_pose_null"):
        add(Case(M, [*D, "--data", f"{{{name}}}", "--out", f"{{tmp}}/m_{name}", "--seed", "1"], expect="accept",
                 slow=True, check=_wrote(f"m_{name}")))
    add(Case(M, ["study", "{s_ok}", "--out", "{dangling}"], message="dangling"))
    add(Case(M, [*D, "--data", "{c_good}", "--out", "{dangling}"], message="dangling"))
    add(Case(M, [*D, "--data", "{c_latin1}", "--out", "{tmp}/m_latin1"], message="UTF-8"))
    add(Case(M, ["worstcase", *G, "--budget", "{c_good}", *P], message="c_good.csv"))
    add(Case(M, [*D, "--data", "{b_bom}", "--out", "{tmp}/m_tomlascsv"], message="b_bom.toml"))
    add(Case(M, [*D, "--data", "{c_crlf}", "--out", "{tmp}/m_crlf", "--seed", "1"], expect="accept", slow=True,
             check=_wrote("m_crlf")))
    add(Case(M, [*D, "--data", "{c_quoted}", "--out", "{tmp}/m_quoted", "--seed", "1"], expect="accept", slow=True,
             check=_wrote("m_quoted")))
    add(Case(M, [*D, "--data", "{c_trailing_comma}", "--out", "{tmp}/m_trail", "--seed", "1"], expect="accept",
             slow=True, check=_wrote("m_trail")))
    add(Case(M, [*D, "--data", "{c_blank_lines}", "--out", "{tmp}/m_blank", "--seed", "1"], expect="accept",
             slow=True, check=_wrote("m_blank")))
    # ------------------------------------------------------------------ silently accepted
    S = "silently accepted"
    add(Case(S, [*D, "--data", "{c_inch}", "--out", "{tmp}/s_inch"], message="inch"))
    add(Case(S, [*D, "--data", "{c_inch_all}", "--out", "{tmp}/s_inch_all"], message="inch"))
    add(Case(S, [*D, "--data", "{c_um}", "--out", "{tmp}/s_um"], message="µm"))
    add(Case(S, [*D, "--data", "{c_rad}", "--out", "{tmp}/s_rad"], message="radian"))
    add(Case(S, [*D, "--data", "{c_kelvin}", "--out", "{tmp}/s_kelvin"], message="kelvin"))
    # 20-28 degrees C in Fahrenheit (68-82) are legal temperatures in degrees C (an oven test): run, with a warning
    add(Case(S, [*D, "--data", "{c_fahrenheit}", "--out", "{tmp}/s_fahrenheit", "--seed", "1"], expect="accept",
             warning="degrees F", slow=True, check=_wrote("s_fahrenheit")))
    add(Case(S, ["study", "{s_sweep_delta_model}", "--out", "{tmp}/s_sweep"], message="a sweep changes"))
    # overlapping groups are legitimate (each group's closed index is its own); clashing names are not
    add(Case(S, ["sobol", *G, "--budget", "{b_overlap_groups}", *P, "--samples", "256", "--json"], expect="accept"))
    add(Case(S, ["sobol", *G, "--budget", "{b_overlap_groups}", *P, "--samples", "256", "--group",
                 "g1=theta_3,b_1"], message="defined twice"))
    add(Case(S, ["sobol", *G, "--budget", "{b_same_groups}", *P, "--samples", "256"], message="same inputs"))
    add(Case(S, ["sobol", *G, "--budget", "{b_clearance_group}", *P, "--samples", "256"], message="clearance"))
    add(Case(S, ["sobol", *G, *B, *P, "--samples", "256", "--group", "g1=theta_1,theta_2", "--group",
                 "g2=theta_2,theta_1"], message="same inputs"))
    add(Case(S, ["sobol", *G, "--budget", "{b_group_dup}", *P, "--samples", "256"], message="theta_1"))
    add(Case(S, ["sobol", *G, "--budget", "{b_group_is_input}", *P, "--samples", "256"], message="b_2"))
    add(Case(S, ["montecarlo", *G, "--budget", "{b_discrete_overflow}", *P, "--samples", "4096", "--seed", "1",
                 "--json"], expect="accept", check=None))
    add(Case(S, ["montecarlo", *G, "--budget", "{b_discrete_tiny}", *P, "--samples", "4096", "--seed", "1",
                 "--json"], expect="accept"))
    add(Case(S, ["montecarlo", *G, "--budget", "{b_discrete_neg}", *P], message="weights"))
    add(Case(S, ["montecarlo", *G, "--budget", "{b_discrete_zero}", *P], message="weights"))
    # ------------------------------------------------------------------ leftovers and permissions
    L = "leftovers & permissions"
    add(Case(L, ["study", "{s_ok}", "--out", "{tmp}/l_mode"], expect="accept", slow=True, check=_mode_ok("l_mode")))
    add(Case(L, [*D, "--data", "{c_good}", "--out", "{tmp}/l_dmode", "--seed", "1"], expect="accept", slow=True,
             check=_mode_ok("l_dmode")))
    add(Case(L, ["study", "{s_ok}", "--out", "{tmp}/link", "--force"], expect="accept", slow=True,
             setup=_earlier_output_behind_link, check=_no_leftovers("link")))
    add(Case(L, [*D, "--data", "{c_good}", "--out", "{tmp}/link", "--force", "--seed", "1"], expect="accept",
             slow=True, setup=_earlier_output_behind_link, check=_no_leftovers("link")))
    add(Case(L, ["study", "{s_ok}", "--out", "{tmp}/link"], message="exists", setup=_earlier_output_behind_link))
    add(Case(L, ["study", "{s_ok}", "--out", "{tmp}/earlier", "--force"], expect="accept", slow=True,
             setup=lambda root: _earlier_output(root / "earlier"), check=_mode_ok("earlier")))
    for kind in ("geometry", "budget"):
        add(Case(L, ["init", kind, f"{{tmp}}/mode_{kind}.toml"], expect="accept",
                 check=lambda root, kind=kind: _file_mode_ok(root / f"mode_{kind}.toml")))
    out += second_cases()
    return out


#: Where the second corpus's cases start (``python -m tests.bad_corpus --second`` runs them alone).
SECOND = "second: "


def second_cases() -> list[Case]:
    """The second corpus (regions, simulate, init, --formats, --max-gb, values in the wrong unit, grid sizes)."""
    out: list[Case] = []

    def add(case: Case) -> None:
        case.id = SECOND + case.id
        out.append(case)

    T, H, M, S, L = "tracebacks", "hangs", "messages", "silently accepted", "leftovers & permissions"
    sim = ["simulate", *G, *B, "--seed", "1"]
    # ------------------------------------------------------------------ region files, in every command taking one
    for name, msg in (("r_reversed", "lo < hi"), ("r_zero", "lo < hi"), ("r_nan", "finite"), ("r_inf", "finite"),
                      ("r_missing_y", "y_mm is missing"), ("r_unknown", "z_mm"), ("r_string", "x_mm"),
                      ("r_phi_string", "phi_deg"), ("r_phi_bool", "phi_deg"), ("r_empty", "missing"),
                      ("r_three", "[lo, hi]"), ("r_table", "x_mm"), ("r_far", "stroke")):
        add(Case(M, ["sensitivity", *G, "--region", f"{{{name}}}", "--grid", "3"], message=msg))
    for command in (["worstcase", *G, *B], ["montecarlo", *G, *B, "--samples", "256", "--seed", "1"]):
        add(Case(M, [*command, "--region", "{r_phi_string}", "--grid", "3"], message="phi_deg"))
    add(Case(M, ["allocate", *G, "--region", "{r_string}", "--classes", "example", "--spec-position-um", "150",
                 "--grid", "3"], message="x_mm"))
    add(Case(M, [*sim, "--poses", "9", "--region", "{r_table}", "--out", "{tmp}/c.csv"], message="x_mm"))
    add(Case(M, ["study", "{s_region_file}", "--out", "{tmp}/st_region"], message="unknown region preset"))
    add(Case(M, ["study", "{s_region_reversed}", "--out", "{tmp}/st_region2"], message="lo < hi"))
    add(Case(M, ["sensitivity", *G, "--region", "{r_bom}", "--grid", "2", "--json"], expect="accept"))
    add(Case(M, ["sensitivity", *G, "--region", "{r_int}", "--grid", "2", "--json"], expect="accept"))
    # ------------------------------------------------------------------ grids and campaigns past the machine
    add(Case(H, ["sensitivity", *G, "--region", "u-shape", "--grid", "3000"], message="use a smaller --grid"))
    add(Case(H, ["sensitivity", *G, "--region", "u-shape", "--grid", "100000"], message="memory"))
    add(Case(H, ["worstcase", *G, *B, "--region", "u-shape", "--grid", "100000"], message="memory"))
    add(Case(H, ["montecarlo", *G, *B, "--region", "u-shape", "--grid", "100000", "--samples", "256"],
             message="memory"))
    add(Case(H, ["--max-gb", "0.001", "sensitivity", *G, "--region", "u-shape", "--grid", "30"], message="--max-gb"))
    add(Case(H, ["--max-gb", "0.001", "worstcase", *G, *B, "--region", "u-shape", "--grid", "300"],
             message="--max-gb"))
    add(Case(H, [*sim, "--poses", "1000000000", "--out", "{tmp}/c.csv"], message="use fewer poses or visits"))
    add(Case(H, [*sim, "--poses", "9", "--visits", "100000000", "--out", "{tmp}/c.csv"], message="memory"))
    add(Case(H, ["--max-gb", "0.01", *sim, "--poses", "900", "--out", "{tmp}/c.csv"], message="--max-gb"))
    add(Case(H, ["--max-hours", "1e-9", *sim, "--poses", "9", "--out", "{tmp}/c.csv"], message="--max-hours"))
    add(Case(H, ["--max-hours", "1e-12", "init", "budget", "{tmp}/t.toml"], message="--max-hours"))
    add(Case(H, ["--max-gb", "-1", "init", "budget", "{tmp}/t.toml"], status=(2,), message="> 0"))
    add(Case(H, ["--max-gb", "inf", *sim, "--poses", "9", "--out", "{tmp}/c.csv"], status=(2,), message="finite"))
    # ------------------------------------------------------------------ simulate
    add(Case(M, [*sim, "--poses", "0", "--out", "{tmp}/c.csv"], status=(2,), message="positive integer"))
    add(Case(M, [*sim, "--poses", "9", "--visits", "0", "--out", "{tmp}/c.csv"], status=(2,),
             message="positive integer"))
    add(Case(M, [*sim, "--poses", "9", "--effects", "wobble_1=1", "--out", "{tmp}/c.csv"], message="wobble_1"))
    add(Case(M, [*sim, "--poses", "9", "--effects", "scale_2", "--out", "{tmp}/c.csv"], status=(2,),
             message="NAME=VALUE"))
    add(Case(M, [*sim, "--poses", "9", "--effects", "scale_2=1e-4,scale_2=2e-4", "--out", "{tmp}/c.csv"],
             status=(2,), message="scale_2 is given twice"))
    add(Case(M, [*sim, "--poses", "9", "--out", "{tmp}/c.json"], message="CAMPAIGN.csv"))
    add(Case(M, [*sim, "--poses", "9", "--effects", "cyclic_1=0.01", "--out", "{tmp}/c.csv"], message="lead_mm"))
    add(Case(M, [*sim, "--poses", "9", "--registration", "1,2", "--out", "{tmp}/c.csv"], message="--registration"))
    add(Case(M, [*sim, "--poses", "9", "--drift", "nan,0,0", "--out", "{tmp}/c.csv"], message="--drift"))
    add(Case(M, [*sim, "--poses", "9", "--outliers", "1.5", "--out", "{tmp}/c.csv"], message="outliers"))
    add(Case(M, [*sim, "--poses", "9", "--repeatable-fraction", "2", "--out", "{tmp}/c.csv"],
             message="repeatable_fraction"))
    add(Case(M, [*sim, "--poses", "9", "--temperature", "20", "--out", "{tmp}/c.csv"], message="--temperature"))
    add(Case(M, [*sim, "--poses", "9", "--approach", "sideways", "--out", "{tmp}/c.csv"], status=(2,),
             message="sideways"))
    add(Case(M, [*sim, "--poses", "9", "--out", ""], message="--out is empty"))
    add(Case(M, [*sim, "--poses", "9", "--out", "{c_good}"], message="exists"))
    add(Case(M, [*sim, "--poses", "9", "--out", "-", "--json"], message="--json"))
    add(Case(M, [*sim, "--plan", "{tmp}/nowhere.csv", "--out", "{tmp}/c.csv"], message="does not exist"))
    add(Case(M, [*sim, "--plan", "{c_plan_far}", "--out", "{tmp}/c.csv"], message="stroke"))
    add(Case(M, [*D, "--data", "{c_template}", "--out", "{tmp}/d_template"], message="unmeasured plan template"))
    add(Case(M, [*D, "--data", "{c_one_empty}", "--out", "{tmp}/d_one_empty"],
             message="phi_meas: expected a finite number, got empty"))
    add(Case(M, [*sim, "--plan", "{c_plan}", "--out", "{tmp}/c_plan.csv"], expect="accept",
             check=_wrote(".", "c_plan.csv")))
    add(Case(M, [*sim, "--poses", "9", "--region", "{r_far}", "--out", "{tmp}/c.csv"], message="stroke"))
    add(Case(M, ["simulate", *G, *B, "--poses", "4", "--out", "{tmp}/deep/er/c.csv", "--seed", "1"],
             expect="accept", check=_wrote("deep/er", "c.csv")))
    # values in the wrong unit: refused where they cannot be, warned where they are legal but unlikely
    add(Case(S, [*sim, "--poses", "9", "--temperature", "293,301", "--out", "{tmp}/c.csv"], message="kelvin"))
    add(Case(S, [*sim, "--poses", "9", "--instrument-sigma-mm", "2", "--out", "{tmp}/c.csv"], message="units"))
    add(Case(S, [*sim, "--poses", "9", "--instrument-sigma-deg", "5", "--out", "{tmp}/c.csv"], message="units"))
    add(Case(S, [*sim, "--poses", "9", "--effects", "backlash_1=20", "--out", "{tmp}/c.csv"], message="units"))
    add(Case(S, [*sim, "--poses", "9", "--effects", "scale_2=500", "--out", "{tmp}/c.csv"], message="units"))
    add(Case(S, [*sim, "--poses", "9", "--registration", "0,0,1e6", "--out", "{tmp}/c.csv"], message="units"))
    add(Case(S, [*D, "--data", "{c_good}", "--out", "{tmp}/d_sig_um", "--instrument-sigma-mm", "2"], message="µm"))
    add(Case(S, [*D, "--data", "{c_good}", "--out", "{tmp}/d_sig_as", "--instrument-sigma-deg", "1.8"],
             message="arcsec"))
    add(Case(S, [*D, "--data", "{c_perfect}", "--out", "{tmp}/d_sig_perf", "--instrument-sigma-mm", "0.002"],
             message="scatter"))
    add(Case(S, ["worstcase", *G, "--budget", "{b_mm_for_um}", *P], expect="accept", warning="too large"))
    add(Case(S, ["worstcase", *G, "--budget", "{b_arcsec_for_deg}", *P], expect="accept", warning="too large"))
    add(Case(S, ["worstcase", *G, "--budget", "{b_sd_mm_for_um}", *P, "--k-sigma", "3"], expect="accept",
             warning="too large"))
    add(Case(S, ["montecarlo", *G, "--budget", "{b_mm_for_um}", *P, "--samples", "1024", "--seed", "1"],
             expect="accept", warning="too large"))
    add(Case(S, ["sobol", *G, "--budget", "{b_arcsec_for_deg}", *P, "--samples", "256", "--seed", "1"],
             expect="accept", warning="too large"))
    # ------------------------------------------------------------------ init
    add(Case(M, ["init", "budget", ""], message="empty"))
    add(Case(M, ["init", "budget", " "], message="empty"))
    add(Case(M, ["init", "wobble", "{tmp}/t.toml"], status=(2,), message="wobble"))
    add(Case(M, ["init", "region", "{c_good}"], message="exists"))
    add(Case(M, ["init", "region", "{tmp}"], message="exists"))
    add(Case(S, ["init", "budget", "-"], expect="accept",
             check=lambda root: None if not (root / "-").exists() else "wrote a file named '-'"))
    add(Case(T, ["init", "region", "{tmp}/new/deeper/r.toml"], expect="accept",
             check=lambda root: _init_reads_region(root / "new/deeper/r.toml")))
    add(Case(L, ["init", "region", "{tmp}/mode_region.toml"], expect="accept",
             check=lambda root: _file_mode_ok(root / "mode_region.toml")))
    # ------------------------------------------------------------------ study --formats
    add(Case(M, ["study", "{s_formats}", "--out", "{tmp}/f1", "--formats", "pdf"], message="formats"))
    add(Case(M, ["study", "{s_formats}", "--out", "{tmp}/f2", "--formats", ""], message="formats"))
    add(Case(M, ["study", "{s_formats}", "--out", "{tmp}/f3", "--formats", ","], message="formats"))
    add(Case(M, ["study", "{s_formats}", "--out", "{tmp}/f4", "--formats", "xlsx"], expect="accept", slow=True,
             check=lambda root: None if list((root / "f4").rglob("*.xlsx")) else "no workbook written"))
    add(Case(M, ["study", "{s_formats}", "--out", "{tmp}/f5", "--formats", "PNG, svg"], expect="accept", slow=True,
             check=lambda root: None if list((root / "f5").rglob("*.svg")) else "no svg written"))
    # ------------------------------------------------------------------ yield and plan (the newest commands)
    y = ["yield", *G, *B]
    add(Case(M, [*y, *P, "--spec-position-um", "0"], status=(2,), message="> 0"))
    add(Case(M, [*y, *P, "--spec-position-um", "nan"], status=(2,), message="finite"))
    for value, msg in (("-inf", "finite"), ("-1e5", "> 0"), ("-nan", "finite"), ("-.5", "> 0")):  # not "one argument"
        add(Case(M, [*y, *P, "--spec-position-um", value], status=(2,), message=msg))
    add(Case(M, [*y, "--pose", "0", "-1e5", "0", "--spec-position-um", "100"], message="stroke"))
    add(Case(S, [*y, *P, "--spec-position-um", "0.06"], message="another unit"))
    add(Case(M, [*y, "--pose", "0", "1000", "0", "--spec-position-um", "100"], message="stroke"))
    add(Case(M, [*y, *P, "--spec-position-um", "100", "--spec-phi-arcsec", "-1"], status=(2,), message="> 0"))
    # refused by the byte count before anything is allocated (not by a MemoryError on the way): the machine's memory
    add(Case(H, [*y, "--region", "u-shape", "--grid", "100000", "--spec-position-um", "100"],
             message="exact yield at 10000000000 poses needs"))
    add(Case(H, ["yield", *G, "--budget", "{b_correlated}", *P, "--spec-position-um", "100", "--samples",
                 "1000000000000"], message="Monte Carlo of 1000000000000 samples at 1 pose(s) needs"))
    add(Case(H, ["yield", *G, "--budget", "{b_correlated}", "--region", "u-shape", "--grid", "100000",
                 "--spec-position-um", "100"], message="of memory, this machine has"))
    add(Case(H, ["--max-gb", "0.001", *y, "--region", "u-shape", "--grid", "300", "--spec-position-um", "100"],
             message="more than --max-gb"))
    add(Case(H, ["--max-gb", "0.01", "yield", *G, "--budget", "{b_no_density}", *P, "--spec-position-um", "8",
                 "--samples", "20000"], message="Monte Carlo of 20000 samples at 1 pose(s) needs"))   # ran unsized
    add(Case(S, ["yield", *G, "--budget", "{b_no_density}", *P, "--spec-position-um", "0.5", "--samples", "2000"],
             expect="accept", warning="below 1 µm"))     # the fallback said nothing, then its text: a traceback
    add(Case(H, ["--max-gb", "4", "study", "{s_sweep_histograms}", "--out", "{tmp}/sw"],
             message="draws at 3000 histogram poses; with the largest analysis"))
    add(Case(M, [*y, *P, "--spec-position-um", "100", "--target", "1e-30"], status=(2,), message="[1e-12, 0.01]"))
    add(Case(M, [*y, *P, "--spec-position-um", "100", "--target", "0.5"], status=(2,), message="[1e-12, 0.01]"))
    for spec in ("1e4", "1e9"):        # beyond the worst case (140 µm): P = 0 exactly, was "more than 2^23 terms"
        add(Case(M, [*y, *P, "--spec-position-um", spec, "--spec-phi-arcsec", spec, "--json"], expect="accept",
                 slow=True))
    al = ["allocate", *G, "--region", "u-shape", "--classes", "example", "--grid", "2", "--json"]
    add(Case(S, [*al, "--spec-position-um", "0.08"], expect="accept", warning="below 1 µm"))
    add(Case(S, [*al, "--spec-position-um", "80", "--spec-phi-arcsec", "0.03"], expect="accept", warning="below 1 arcsec"))
    add(Case(M, [*al, "--spec-position-um", "80", "--spec-percentile", "99.99999"], message="p99.99999"))
    add(Case(T, ["yield", "--geometry", "{g_parallel}", *B, *P, "--spec-position-um", "100"], message="singular"))
    pl = ["plan", *G, *B, "--poses", "9", "--visits", "2", "--out", "{tmp}/p.csv"]
    add(Case(H, ["plan", *G, *B, "--effects", "backlash_1", "--poses", "9", "--visits", "1000000000", "--out",
                 "{tmp}/p.csv"], message="a campaign plan of 1000000000 visits of 405 candidate poses needs"))
    add(Case(M, [*pl, "--effects", "nonsense_1"], message="unknown effect"))
    add(Case(M, [*pl, "--effects", "scale_2", "--region", "0", "1"], message="got 2 values"))   # was usage (2)
    add(Case(M, [*pl, "--effects", "scale_2", "--region", "nowhere"], message="nowhere"))
    add(Case(M, [*pl, "--effects", ","], message="at least one effect"))
    add(Case(M, [*pl, "--effects", "cyclic_1"], message="lead_mm"))
    add(Case(S, [*pl, "--effects", "cyclic_1,scale_2,cyclic_1"], message="--effects names cyclic_1 twice",
             id="plan --effects cyclic_1,scale_2,cyclic_1"))
    for name in ("p.json", "p.xlsx", "p.csv.txt"):
        add(Case(S, [*pl[:-1], f"{{tmp}}/{name}", "--effects", "scale_2"], message="name it FILE.csv",
                 id=f"plan --out {name}"))
    add(Case(M, ["plan", *G, *B, "--effects", "scale_2", "--poses", "0", "--visits", "2", "--out", "{tmp}/p.csv"],
             status=(2,), message="positive integer"))
    return out


def _init_reads_region(path: Path) -> str | None:
    from prp3mc.kinematics.geometry import Region
    try:
        Region.from_toml(path)
    except Exception as exc:  # noqa: BLE001
        return f"{path.name} does not read back: {exc}"
    return None


def _earlier_output(folder: Path) -> None:
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text("{}")


def _earlier_output_behind_link(root: Path) -> None:
    _earlier_output(root / "target")
    (root / "link").symlink_to(root / "target")


def _no_leftovers(name: str) -> Callable:
    def check(root: Path) -> str | None:
        left = [p.name for p in root.iterdir() if p.name.startswith(f".{name}.") or p.name.startswith(".target.")]
        if left:
            return f"left behind: {', '.join(left)}"
        if not (root / name / "report.html").exists():
            return f"{name}/report.html was not written"
        return None
    return check


def _file_mode_ok(path: Path) -> str | None:
    umask = os.umask(0)
    os.umask(umask)
    mode, want = path.stat().st_mode & 0o777, 0o666 & ~umask
    return None if mode == want else f"{path.name} has mode {oct(mode)}, the umask gives {oct(want)}"


def _init_reads(path: Path, kind: str) -> str | None:
    from prp3mc import Budget, Geometry
    from prp3mc.allocation.classes import ClassMenu
    from prp3mc.study.reader import Study
    reader = {"geometry": Geometry.from_toml, "budget": Budget.from_toml, "study": Study.from_toml,
              "classes": ClassMenu.from_toml}[kind]
    try:
        reader(path)
    except Exception as exc:  # noqa: BLE001
        return f"{path.name} does not read back: {exc}"
    return None


def expand(argv: list, paths: dict, tmp: str) -> list:
    """``argv`` with its placeholders filled (bytes where a path is not UTF-8)."""
    out = []
    for a in argv:
        key = a[1:-1] if a.startswith("{") and a.endswith("}") else None
        if key in paths and isinstance(paths[key], bytes):
            out.append(paths[key])
        else:
            out.append(a.format(tmp=tmp, **{k: v for k, v in paths.items() if isinstance(v, str)}))
    return out


def judge(case: Case, code: int | None, out: str, err: str, root: Path, existed: bool, out_dir) -> str | None:
    """What went wrong with one run (None: nothing)."""
    if code is None:
        return "hang (timeout)"
    for marker in ("Traceback", "Fatal Python error", "Exception ignored"):
        if marker in err:
            return f"{marker}: {err.strip().splitlines()[-1][:160]}"
    if case.expect == "refuse":
        if code not in case.status:
            return f"exit {code}, expected {case.status}: {err.strip()[:160]}"
        if err.count("\n") != 1:
            return f"{err.count(chr(10))} lines on stderr: {err.strip()[:160]}"
        if case.message not in err:
            return f"message lacks {case.message!r}: {err.strip()[:200]}"
        if out_dir is not None and not existed and os.path.lexists(out_dir) and not os.path.islink(out_dir):
            return f"wrote {out_dir!r} although it refused"
        return None
    if code != 0:
        return f"exit {code}: {err.strip()[:200]}"
    if case.warning and case.warning not in err:
        return f"no warning with {case.warning!r}: {err.strip()[:200]}"
    return case.check(root) if case.check else None


def _out_of(argv: list):
    return argv[argv.index("--out") + 1] if "--out" in argv else None


def run_one(case: Case, argv: list, tmp: Path, timeout: float = 300.0) -> str | None:
    """Run one case (its argv expanded) in a real process in the folder ``tmp``; what went wrong, or None."""
    if case.setup:
        case.setup(tmp)
    out_dir = _out_of(argv)
    existed = out_dir is not None and os.path.lexists(out_dir)
    try:
        r = subprocess.run([sys.executable, "-m", "prp3mc", *argv], capture_output=True, timeout=timeout, cwd=tmp)
        code, out, err = r.returncode, r.stdout.decode(errors="replace"), r.stderr.decode(errors="replace")
    except subprocess.TimeoutExpired:
        code, out, err = None, "", ""
    return judge(case, code, out, err, tmp, existed, out_dir)


def run(only: str | None = None, timeout: float = 300.0, root: Path | None = None, jobs: int = 1,
        ids: set | None = None) -> dict:
    """Run the corpus (or the cases of class ``only``, or of ``ids``) in real processes; return
    {class: [total, bad]} and print each case."""
    from concurrent.futures import ThreadPoolExecutor
    root = root or Path(os.environ.get("TMPDIR", "/tmp")) / f"prp3mc_corpus_{os.getpid()}"
    paths = prepare(root / "files")
    selected = [c for c in cases() if only in (None, c.cls) and (ids is None or c.id in ids)]

    def one(k_case):
        k, case = k_case
        tmp = str(root / f"run{k}")
        os.makedirs(tmp, exist_ok=True)
        argv = expand(case.argv, paths, tmp)
        t0 = time.time()
        return case, run_one(case, argv, Path(tmp), timeout), time.time() - t0

    counts = {c: [0, 0] for c in CLASSES}
    with ThreadPoolExecutor(jobs) as pool:
        for case, problem, took in pool.map(one, enumerate(selected)):
            counts[case.cls][0] += 1
            counts[case.cls][1] += problem is not None
            print(f"{'BAD ' if problem else 'ok  '}{took:6.1f}s [{case.cls}] {case.id}"
                  + (f"\n      {problem}" if problem else ""), flush=True)
    return counts


def signal_loop(root: Path, n: int, seed: int = 0, paths: dict | None = None, log=lambda line: None) -> dict:
    """Send SIGTERM or SIGINT at a random time near the end of a study and of a discrepancy, ``n`` runs.

    Each command is timed undisturbed (after a first run that fills the
    compiled-code caches), and the time is kept up to date as the machine's
    load changes (a run that ends before its signal is timed, one interrupted
    later than the estimate ran at least that long); the signal comes at
    60-110 % of it. A run ends well when it completed (exit 0, its folder whole, no
    traceback) or did not and changed nothing (exit 130 or 143, no folder,
    no traceback, no leftovers). Returns ``{"total", "bad", "outcomes", "problems"}``.
    """
    import random
    import shutil
    import signal
    paths = paths or prepare(root / "files")
    rng = random.Random(seed)
    commands = {"study": ["study", paths["s_signal"], "--out", "OUT"],
                "discrepancy": [*D, "--data", paths["c_good"], "--out", "OUT", "--seed", "1"]}
    marks = {"study": "summary.json", "discrepancy": "discrepancy.json"}

    def start(argv, out):
        return subprocess.Popen([sys.executable, "-m", "prp3mc", *[str(out) if a == "OUT" else a for a in argv]],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=root)

    took = {}
    for kind, argv in commands.items():
        for _ in range(2):   # the first run fills the compiled-code caches; the second is the one timed
            out = root / f"calibrate_{kind}"
            shutil.rmtree(out, ignore_errors=True)
            t0 = time.time()
            start(argv, out).communicate()
            took[kind] = time.time() - t0
    result = {"total": 0, "bad": 0, "outcomes": {}, "problems": [], "calibration_s": dict(took)}
    for t in range(n):
        kind = ("study", "discrepancy")[t % 2]
        sig = signal.SIGTERM if rng.random() < 0.6 else signal.SIGINT
        out = root / f"sig{t}"
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.time()
        run = start(commands[kind], out)
        when = took[kind] * rng.uniform(0.6, 1.1)
        try:
            run.wait(timeout=when)
        except subprocess.TimeoutExpired:
            run.send_signal(sig)
        _, err = run.communicate(timeout=600)
        err = err.decode(errors="replace")
        whole = (out / marks[kind]).is_file() and (out / "report.html").is_file()
        left = [p.name for p in root.iterdir() if p.name.startswith(f".sig{t}.")]
        clean = not any(m in err for m in ("Traceback", "Fatal Python error", "Exception ignored"))
        ok = clean and not left and ((run.returncode == 0 and whole)
                                     or (run.returncode in (130, 143) and not os.path.lexists(out)))
        key = f"{kind} {sig.name} exit {run.returncode}{' folder whole' if whole else ''}"
        if run.returncode == 0 and whole and time.time() - t0 < when:   # it ended before the signal came
            key = f"{kind} ended before the signal"
            took[kind] = 0.5 * (took[kind] + time.time() - t0)        # the machine is faster now: aim earlier
        elif run.returncode in (130, 143):
            took[kind] = max(took[kind], when)    # it would have run at least this long
        result["outcomes"][key] = result["outcomes"].get(key, 0) + 1
        result["total"] += 1
        if not ok:
            result["bad"] += 1
            result["problems"].append(f"{key} at {when:.1f} s: leftovers {left}; {err.strip()[-300:]}")
        log(f"{'ok ' if ok else 'BAD'} {t:3d} {key} (signal at {when:.1f} s, ran {time.time() - t0:.1f} s)"
            + ("" if ok else f"\n      {err.strip()[-300:]}"))
    return result


if __name__ == "__main__":
    import argparse
    parser = argparse.ArgumentParser()
    parser.add_argument("--only", default=None)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--root", type=Path, default=None)
    parser.add_argument("--timeout", type=float, default=300.0)
    parser.add_argument("--signals", type=int, default=0, help="run the signal loop this many times instead")
    parser.add_argument("--rerun-bad", type=Path, default=None, help="run only the cases a log of this runner "
                        "printed as BAD")
    a = parser.parse_args()
    rerun = None
    if a.rerun_bad:
        rerun = {line.split("] ", 1)[1] for line in a.rerun_bad.read_text(errors="replace").splitlines()
                 if line.startswith("BAD ")}
    if a.signals:
        root = a.root or Path(os.environ.get("TMPDIR", "/tmp")) / f"prp3mc_signals_{os.getpid()}"
        root.mkdir(parents=True, exist_ok=True)
        result = signal_loop(root, a.signals, log=lambda line: print(line, flush=True))
    else:
        result = run(a.only, timeout=a.timeout, root=a.root, jobs=a.jobs, ids=rerun)
    print(json.dumps(result))
