"""The study file: a TOML file naming the configurations to compare and the analyses to run.

A study names the configurations to compare (geometry, test region,
orientation), one error budget, the analyses wanted and their sizes, and one
seed. :func:`prp3mc.study.runner.run_study` runs it.

Study file layout (mm and degrees; every key but ``[[configuration]]`` is
optional; paths are relative to the study file)::

    name = "paper_reproduction"       # default: the file's stem
    title = "U versus Delta"          # heading of the report
    description = "..."               # a paragraph for the report
    seed = 20240611                   # default: fresh, recorded in the outputs
    budget = "paper"                  # budget preset or TOML file
    outputs = ["montecarlo", "sobol", "yield"]  # analyses besides the exact worst case, which always runs
                                      # (yield: the exact yield, with a [spec])

    [worstcase]                       # exact worst case of the linear model
    grid = 201                        # n (n x n poses) or [nx, ny]
    k_sigma = 3.0                     # bound for unbounded (normal) laws

    [montecarlo]
    samples = 131072                  # budget samples, shared by all poses and configurations
    grid = 21
    percentiles = [50, 95, 99, 99.73]
    tolerance_mm = 0.15               # the position spec in mm (older files): see [spec]

    [spec]                            # the accuracy spec: exact yield at every pose of the Monte Carlo grid
    position_um = 150.0               # the position error |(dx, dy)| must stay within it, µm (below 1: a warning)
    phi_arcsec = 60.0                 # |dphi| must stay within it, arcsec (optional; below 1: a warning)

    [sobol]
    samples = 4096                    # base sample size N, a power of two
    grid = 11
    outputs = ["position", "phi"]     # of x, y, phi, position
    groups = { theta = ["theta_1", "theta_2", "theta_3"] }   # besides the budget's

    [[configuration]]                 # one per configuration compared, at least one
    name = "u-shape"                  # unique label (default: the geometry's name)
    geometry = "u-shape"              # geometry preset or TOML file
    region = "u-shape"                # region preset, or { x_mm = [lo, hi], y_mm = [lo, hi] }
    phi_deg = 0.0                     # default: the region preset's orientation, else 0
    poses = [[0.0, 100.0, 0.0]]       # poses of the error histograms (default: the region's
                                      # centre and its worst-case maximum and minimum)
    reference_position_um = [110, 150]  # a published worst-case range to compare with
    reference = "paper, Fig. 4"         # where that range comes from

    [allocation]                      # least-cost tolerance classes meeting a spec (prp3mc allocate)
    classes = "example"               # the bundled classes preset, or a classes TOML file
    spec_position_um = 80.0           # worst-case position error bound, µm; and/or
    spec_phi_arcsec = 120.0           # worst-case |dphi| bound, arcsec
    spec_percentile = 99.73           # optional: the position spec bounds this percentile instead
    samples = 20000                   # Monte Carlo samples confirming it (only with spec_percentile)
    grid = 41                         # n or [nx, ny] (default: the [worstcase] grid)
    front = true                      # also the cost-accuracy Pareto front (default true)
    configurations = ["u-shape"]      # default: every configuration (a swept one: its base's name)

    [sweep]                           # optional: expand every configuration over the cartesian
    "leg.3.a_mm" = [200, 220, 240]    # product of geometry parameters (keys as in a geometry
    "leg.*.e_mm" = [10, 20, 30]       # file, legs 1-3 or * for all; see prp3mc.study.sweep)

With a spec (and ``yield`` among the outputs, as by default), every configuration gets its exact yield (P(position > S),
P(``|δφ|`` > Z), P(either), Ppk, the exact quantiles; :mod:`prp3mc.study.spec`) at
every pose of its Monte Carlo grid. One spec, not two: ``[montecarlo]
tolerance_mm`` is the same position spec in mm; without ``[spec]`` it is
taken as ``position_um = 1000 * tolerance_mm``, with ``[spec]`` it may be
left out (the Monte Carlo run counts against ``[spec]``), and if both are given
they must agree. A spec below 1 µm or 1 arcsec is refused, naming the unit.

The allocation runs for every configuration (or those listed), each over
its own geometry and test region; its budget is the classes' laws, with the
study budget's ``[effects]`` held fixed (see :mod:`prp3mc.study.allocation`).

A mistake (unknown key, wrong type, unknown preset, impossible value, a pose
or region outside the workspace) raises :class:`~prp3mc.errors.StudyError`
whose message reads ``FILE:LINE: reason``.

Randomness: the study seed gives one Monte Carlo seed, one Sobol seed and
one seed of the allocation's Monte Carlo confirmation, each shared by all
configurations, swept ones included (common random numbers, so differences
between configurations are not blurred by sampling noise).
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .._toml import read_text_file
from ..errors import Prp3mcError, ResourceError, StudyError, UnknownPresetError
from ..limits import check, worstcase_estimate
from ..kinematics.chain import check_poses
from ..kinematics.geometry import REGION_PRESETS, Geometry, Region
from ..model.budget import Budget
from ..montecarlo.propagation import MIN_SAMPLES as MIN_MC_SAMPLES, PERCENTILES
from ..units import OUTPUTS
from .allocation import AllocationSpec, read_allocation
from .bundled import STUDIES_DIR, bundled_studies
from .spec import YieldSpec, read_spec
from .sweep import is_number, read_sweep

__all__ = ["Study", "StudyConfiguration", "bundled_studies", "STUDIES_DIR", "ANALYSES"]


#: Analyses a study can ask for besides the exact worst case (which always runs).
ANALYSES = ("montecarlo", "sobol", "yield")
_DEFAULT = {"worstcase_grid": (101, 101), "mc_samples": 1 << 16, "mc_grid": (11, 11), "sobol_samples": 1 << 12,
            "sobol_grid": (5, 5), "sobol_outputs": ("position", "phi")}
_REDUCED = {"worstcase_grid": 21, "mc_samples": 1 << 14, "mc_grid": 5, "sobol_samples": 1 << 10, "sobol_grid": 3}


# ----------------------------------------------------------------- spec
@dataclass(frozen=True, slots=True)
class StudyConfiguration:
    """One configuration of a study: a geometry over a test region.

    Attributes
    ----------
    name : str
    geometry : Geometry
    region : Region
        Test region at the configuration's orientation ``region.phi_deg``.
    poses : tuple of (x_mm, y_mm, phi_deg) or None
        Poses of the error histograms, ``[x_mm, y_mm, phi_deg]``; None: the
        region's centre and the worst-case maximum and minimum.
    reference_position_um : (lo, hi) or None
        A published worst-case position-error range to compare with, µm.
    reference : str
    parameters : tuple of (key, value)
        Sweep parameters of an expanded configuration, keys as written in the
        ``[sweep]`` table; empty for a configuration of the file.
    """

    name: str
    geometry: Geometry
    region: Region
    poses: tuple | None = None
    reference_position_um: tuple[float, float] | None = None
    reference: str = ""
    parameters: tuple = ()


@dataclass(frozen=True, slots=True)
class Study:
    """A validated study (see the module docstring for the file layout).

    Attributes
    ----------
    name, title, description : str
    seed : int or None
    budget : Budget
    configurations : tuple of StudyConfiguration
    outputs : tuple of str
        Analyses to run besides the worst case, a subset of :data:`ANALYSES`.
    worstcase_grid, mc_grid, sobol_grid : (nx, ny)
    k_sigma : float or None
    mc_samples : int
    percentiles : tuple of float
    tolerance_mm : float or None
        The Monte Carlo run's tolerance, mm: the position spec (``spec.position_um / 1000``).
    spec : YieldSpec or None
        The accuracy spec (``[spec]``, or ``[montecarlo] tolerance_mm`` alone).
    sobol_samples : int
        Base sample size N of Saltelli's scheme, a power of two.
    sobol_outputs : tuple of str
    sobol_groups : dict of str to tuple of str
    allocation : AllocationSpec or None
        The ``[allocation]`` table.
    sweep : tuple of (key, tuple of values)
        The ``[sweep]`` table in file order; empty without one.
    source : str
        The file it was read from.
    """

    name: str
    budget: Budget
    configurations: tuple
    seed: int | None = None
    title: str = ""
    description: str = ""
    outputs: tuple = ANALYSES
    worstcase_grid: tuple = _DEFAULT["worstcase_grid"]
    k_sigma: float | None = None
    mc_samples: int = _DEFAULT["mc_samples"]
    mc_grid: tuple = _DEFAULT["mc_grid"]
    percentiles: tuple = PERCENTILES
    tolerance_mm: float | None = None
    spec: YieldSpec | None = None
    sobol_samples: int = _DEFAULT["sobol_samples"]
    sobol_grid: tuple = _DEFAULT["sobol_grid"]
    sobol_outputs: tuple = _DEFAULT["sobol_outputs"]
    sobol_groups: dict = field(default_factory=dict)
    allocation: AllocationSpec | None = None
    sweep: tuple = ()
    source: str = "<study>"

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "Study":
        """Read and validate a study file; mistakes raise StudyError naming the line."""
        path = Path(path)
        text = read_text_file(path, StudyError, "study file")
        return cls.from_text(text, source=str(path), base=path.parent, default_name=path.stem)

    @classmethod
    def from_text(cls, text: str, source: str = "<study>", base: Path | None = None,
                  default_name: str = "study") -> "Study":
        """Validate study TOML ``text``; ``base`` resolves relative file names."""
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            match = re.search(r"at line (\d+)", str(exc))
            line = match.group(1) if match else "?"
            reason = re.sub(r"\s*\(at line \d+, column \d+\)", "", str(exc))
            raise StudyError(f"{source}:{line}: malformed TOML: {reason}") from None
        return _Reader(text, source, base or Path("."), default_name).study(doc)

    @classmethod
    def load(cls, spec: "str | os.PathLike | Study") -> "Study":
        """A Study, a study file, or the name of a bundled study (``paper_reproduction``)."""
        if isinstance(spec, Study):
            return spec
        path = Path(spec)
        if path.suffix == ".toml" or path.exists():
            return cls.from_toml(path)
        known = bundled_studies()
        if str(spec) not in known:
            raise UnknownPresetError(f"unknown study {str(spec)!r}: not a file and not a bundled study "
                                     f"(bundled: {', '.join(known) or 'none found'})")
        return cls.from_toml(STUDIES_DIR / f"{spec}.toml")

    def reduced(self) -> "Study":
        """The same study at test size: grids and sample sizes capped (``--quick``, golden files)."""
        cap = lambda grid, n: (min(grid[0], n), min(grid[1], n))  # noqa: E731
        return replace(self, worstcase_grid=cap(self.worstcase_grid, _REDUCED["worstcase_grid"]),
                       mc_samples=min(self.mc_samples, _REDUCED["mc_samples"]),
                       mc_grid=cap(self.mc_grid, _REDUCED["mc_grid"]),
                       sobol_samples=min(self.sobol_samples, _REDUCED["sobol_samples"]),
                       sobol_grid=cap(self.sobol_grid, _REDUCED["sobol_grid"]),
                       allocation=None if self.allocation is None else self.allocation.reduced())

    def with_budget(self, budget: Budget) -> "Study":
        """The same study with another budget (what-if studies, perturbation tests)."""
        return replace(self, budget=budget)

    def sizes(self) -> dict:
        """Grid and sample sizes of the analyses it runs (for metadata)."""
        out: dict[str, Any] = {"worstcase_grid": list(self.worstcase_grid)}
        if "montecarlo" in self.outputs:
            out.update(montecarlo_samples=self.mc_samples, montecarlo_grid=list(self.mc_grid))
        if "sobol" in self.outputs:
            out.update(sobol_samples=self.sobol_samples, sobol_grid=list(self.sobol_grid))
        if self.spec is not None and "yield" in self.outputs:
            out.update(yield_grid=list(self.mc_grid))
        if self.allocation is not None:
            out.update(self.allocation.sizes(self.worstcase_grid))
        return out


class _Reader:
    """Validation of a parsed study document, pointing errors at their lines."""

    _TOP = {"name", "title", "description", "seed", "budget", "outputs", "worstcase", "montecarlo",
            "sobol", "configuration", "allocation", "sweep", "spec"}
    _TABLES = {"worstcase": {"grid", "k_sigma"},
               "montecarlo": {"samples", "grid", "percentiles", "tolerance_mm"},
               "sobol": {"samples", "grid", "outputs", "groups"}}
    _CONFIG = {"name", "geometry", "region", "phi_deg", "poses", "reference_position_um", "reference"}

    def __init__(self, text: str, source: str, base: Path, default_name: str):
        self.lines = _key_lines(text)
        self.source, self.base, self.default_name = source, base, default_name

    def fail(self, path: tuple, reason: str):
        raise StudyError(f"{self.source}:{self._line(path)}: {reason}")

    def _line(self, path: tuple) -> int | str:
        for k in range(len(path), 0, -1):  # the longest prefix of the path that has a line
            if path[:k] in self.lines:
                return self.lines[path[:k]]
        return 1

    # typed getters -------------------------------------------------------
    def get(self, table: dict, path: tuple, kind: str, default=None):
        if path[-1] not in table:
            return default
        value = table[path[-1]]
        where = ".".join(str(p) if not isinstance(p, int) else f"[{p + 1}]" for p in path).replace(".[", "[")
        checks = {
            "str": lambda v: isinstance(v, str),
            "name": lambda v: isinstance(v, str) and v.strip(". ") != "" and not re.search(r"[/\\\x00-\x1f]", v),
            "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
            "number": is_number,
            "table": lambda v: isinstance(v, dict), "list": lambda v: isinstance(v, list),
        }
        names = {"str": "a string", "int": "an integer", "number": "a finite number", "table": "a table",
                 "list": "an array", "name": "a name for files (no '/', '\\' or control characters, not only dots)"}
        if not checks[kind](value):
            self.fail(path, f"{where} must be {names[kind]}, got {value!r}")
        return value

    def unknown(self, table: dict, allowed: set, path: tuple, what: str):
        for key in table:
            if key not in allowed:
                self.fail(path + (key,), f"unknown key {key!r} in {what} (expected one of "
                          f"{', '.join(sorted(allowed))})")

    def grid(self, table: dict, path: tuple, default: tuple) -> tuple:
        value = table.get(path[-1])
        if value is None:
            return default
        ok_int = lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 2  # noqa: E731
        if ok_int(value):
            value = [value, value]
        if isinstance(value, list) and len(value) == 2 and all(ok_int(v) for v in value):
            try:  # the configurations' grids are checked for feasibility below: refuse what cannot be built
                check(worstcase_estimate(value[0] * value[1], 0))
            except ResourceError as exc:
                self.fail(path, f"{'.'.join(path)}: {exc}")
            return (value[0], value[1])
        self.fail(path, f"{'.'.join(path)} must be an integer n >= 2 (n x n poses) or [nx, ny], got {value!r}")

    def samples(self, table: dict, path: tuple, default: int, power_of_two: bool = False, least: int = 2) -> int:
        n = self.get(table, path, "int", default)
        if n < least:
            self.fail(path, f"{'.'.join(path)} must be at least {least}, got {n}")
        if power_of_two and n & (n - 1):
            self.fail(path, f"{'.'.join(path)} must be a power of two (Saltelli's scheme), got {n}; "
                      f"nearest: {1 << round(math.log2(n))}")
        return n

    # the document --------------------------------------------------------
    def study(self, doc: dict) -> Study:
        self.unknown(doc, self._TOP, (), "the study")
        name = self.get(doc, ("name",), "name", self.default_name)
        seed = self.get(doc, ("seed",), "int")
        if seed is not None and seed < 0:
            self.fail(("seed",), f"seed must be a non-negative integer, got {seed}")
        outputs = self.get(doc, ("outputs",), "list", list(ANALYSES))
        bad = [o for o in outputs if o not in ANALYSES]
        if bad or len(set(outputs)) != len(outputs):
            self.fail(("outputs",), f"outputs must list distinct analyses among {', '.join(ANALYSES)} "
                      f"(the worst case always runs), got {outputs!r}")
        budget_spec = self.get(doc, ("budget",), "str", "paper")
        budget = self.load(("budget",), "budget", Budget.load, budget_spec)
        for key in self._TABLES:
            self.get(doc, (key,), "table", {})
            self.unknown(doc.get(key, {}), self._TABLES[key], (key,), f"[{key}]")
        wc, mc, so = (doc.get(k, {}) for k in ("worstcase", "montecarlo", "sobol"))
        kw: dict[str, Any] = {
            "worstcase_grid": self.grid(wc, ("worstcase", "grid"), _DEFAULT["worstcase_grid"]),
            "k_sigma": self.get(wc, ("worstcase", "k_sigma"), "number"),
            "mc_samples": self.samples(mc, ("montecarlo", "samples"), _DEFAULT["mc_samples"], least=MIN_MC_SAMPLES),
            "mc_grid": self.grid(mc, ("montecarlo", "grid"), _DEFAULT["mc_grid"]),
            "tolerance_mm": self.get(mc, ("montecarlo", "tolerance_mm"), "number"),
            "sobol_samples": self.samples(so, ("sobol", "samples"), _DEFAULT["sobol_samples"], power_of_two=True),
            "sobol_grid": self.grid(so, ("sobol", "grid"), _DEFAULT["sobol_grid"]),
        }
        if kw["k_sigma"] is not None and kw["k_sigma"] <= 0:
            self.fail(("worstcase", "k_sigma"), f"k_sigma must be positive, got {kw['k_sigma']}")
        try:
            budget.bounds(kw["k_sigma"])
        except Prp3mcError as exc:
            self.fail(("budget",), f"budget {budget_spec!r}: {exc} (set [worstcase] k_sigma)")
        if kw["tolerance_mm"] is not None and kw["tolerance_mm"] <= 0:
            self.fail(("montecarlo", "tolerance_mm"), f"tolerance_mm must be > 0 mm (the position spec), "
                      f"got {kw['tolerance_mm']}")
        kw["spec"] = read_spec(self, doc, kw["tolerance_mm"])
        if kw["spec"] is not None:
            kw["tolerance_mm"] = kw["spec"].position_mm
        pct = self.get(mc, ("montecarlo", "percentiles"), "list", list(PERCENTILES))
        if not pct or not all(isinstance(p, (int, float)) and not isinstance(p, bool) and 0 < p < 100
                              for p in pct) or sorted(set(pct)) != list(pct):
            self.fail(("montecarlo", "percentiles"), f"percentiles must be increasing numbers in (0, 100), "
                      f"got {pct!r}")
        kw["percentiles"] = tuple(float(p) for p in pct)
        sob_out = self.get(so, ("sobol", "outputs"), "list", list(_DEFAULT["sobol_outputs"]))
        if not sob_out or any(o not in OUTPUTS for o in sob_out) or len(set(sob_out)) != len(sob_out):
            self.fail(("sobol", "outputs"), f"sobol outputs must be distinct names among "
                      f"{', '.join(OUTPUTS)}, got {sob_out!r}")
        kw["sobol_outputs"] = tuple(sob_out)
        groups = self.get(so, ("sobol", "groups"), "table", {})
        for g, members in groups.items():
            if (not isinstance(members, list) or not members
                    or any(m not in budget.factors for m in members)):
                self.fail(("sobol", "groups", g), f"group {g!r} must list inputs of the budget "
                          f"({', '.join(budget.factors)}), got {members!r}")
            if g in budget.factors or g in budget.groups:
                self.fail(("sobol", "groups", g), f"group {g!r} clashes with an input or a budget group")
        kw["sobol_groups"] = {g: tuple(m) for g, m in groups.items()}
        configs = doc.get("configuration")
        if not isinstance(configs, list) or not configs or not all(isinstance(c, dict) for c in configs):
            self.fail(("configuration",), "a study needs at least one [[configuration]] table")
        kw["sweep"] = read_sweep(self, self.get(doc, ("sweep",), "table", {}))
        if kw["sweep"] and budget.effects and budget.fitted_on is not None:
            self.fail(("sweep",), f"budget {budget.name!r} holds effects fitted on geometry {budget.fitted_on.name!r}: "
                      "a sweep changes that geometry, and fitted effects belong to the machine they were measured "
                      "on; sweep with the budget's inputs alone (drop its [effects] and fitted_on)")
        # a swept configuration is checked value by value when it runs (infeasible ones are reported)
        check = None if kw["sweep"] else kw["worstcase_grid"]
        parsed = tuple(self.configuration(c, k, check, budget) for k, c in enumerate(configs))
        names = [c.name for c in parsed]
        for k, n in enumerate(names):
            if n in names[:k]:
                self.fail(("configuration", k, "name"), f"configuration name {n!r} is used twice")
        kw["allocation"] = read_allocation(self, doc, parsed, kw["worstcase_grid"], kw["k_sigma"])
        return Study(name=name, budget=budget, configurations=parsed, seed=seed,
                     title=self.get(doc, ("title",), "str", ""),
                     description=self.get(doc, ("description",), "str", ""),
                     outputs=tuple(o for o in ANALYSES if o in outputs), source=self.source, **kw)

    def load(self, path: tuple, what: str, loader, spec: str):
        target = self.base / spec if spec.endswith(".toml") else spec
        try:
            return loader(target)
        except Prp3mcError as exc:
            self.fail(path, f"{what} {spec!r}: {exc}")

    def configuration(self, c: dict, k: int, grid: tuple | None, budget: Budget) -> StudyConfiguration:
        p = ("configuration", k)
        self.unknown(c, self._CONFIG, p, f"configuration {k + 1}")
        if "geometry" not in c:
            self.fail(p, f"configuration {k + 1} needs a geometry (preset name or TOML file)")
        geometry = self.load(p + ("geometry",), "geometry", Geometry.load, self.get(c, p + ("geometry",), "str"))
        self.load(p + ("geometry",), "geometry", lambda _: budget.check_geometry(geometry), geometry.name)
        name = self.get(c, p + ("name",), "name", geometry.name)
        region_spec = c.get("region", geometry.name)
        if isinstance(region_spec, str):
            if region_spec not in REGION_PRESETS:
                self.fail(p + ("region",), f"unknown region preset {region_spec!r} (known: "
                          f"{', '.join(REGION_PRESETS)}); or give {{ x_mm = [lo, hi], y_mm = [lo, hi] }}")
            region = Region.from_preset(region_spec)
        elif isinstance(region_spec, dict) and set(region_spec) == {"x_mm", "y_mm"}:
            try:
                region = Region(x_mm=region_spec["x_mm"], y_mm=region_spec["y_mm"])
            except (Prp3mcError, TypeError, ValueError) as exc:
                self.fail(p + ("region",), f"region: {exc}")
        else:
            self.fail(p + ("region",), f"region must be a region preset name or {{ x_mm = [lo, hi], "
                      f"y_mm = [lo, hi] }}, got {region_spec!r}")
        phi = self.get(c, p + ("phi_deg",), "number", region.phi_deg)
        region = Region(region.x_mm, region.y_mm, phi)
        try:
            if grid is not None:
                check_poses(geometry, region.grid(grid))
        except Prp3mcError as exc:
            self.fail(p + (("phi_deg",) if "phi_deg" in c else ("region",)),
                      f"configuration {name!r}: the test region leaves the workspace: {exc}")
        poses = None
        if "poses" in c:
            raw = self.get(c, p + ("poses",), "list")
            try:
                poses = np.array(raw, dtype=float)
            except (TypeError, ValueError):
                poses = np.empty(0)
            if poses.ndim != 2 or poses.shape[1:] != (3,) or not len(poses) or not np.isfinite(poses).all():
                self.fail(p + ("poses",), f"poses must be a non-empty array of [x_mm, y_mm, phi_deg], got {raw!r}")
            try:
                if grid is not None:
                    check_poses(geometry, poses)
            except Prp3mcError as exc:
                self.fail(p + ("poses",), f"configuration {name!r}: {exc}")
            poses = tuple(tuple(float(v) for v in pose) for pose in poses)
        ref = self.get(c, p + ("reference_position_um",), "list")
        if ref is not None:
            if (len(ref) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in ref)
                    or not 0 <= ref[0] <= ref[1]):
                self.fail(p + ("reference_position_um",), f"reference_position_um must be [lo, hi] in µm with "
                          f"0 <= lo <= hi, got {ref!r}")
            ref = (float(ref[0]), float(ref[1]))
        return StudyConfiguration(name=name, geometry=geometry, region=region, poses=poses,
                                  reference_position_um=ref, reference=self.get(c, p + ("reference",), "str", ""))


_HEADER = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r"""^\s*("[^"]*"|'[^']*'|[A-Za-z0-9_\-]+)\s*=""")


def _key_lines(text: str) -> dict[tuple, int]:
    """Line (1-based) where every table and key of a TOML text is defined.

    Paths are tuples of keys; the k-th ``[[configuration]]`` table is
    ``("configuration", k)``. Keys of one-line inline tables are found too.
    """
    lines: dict[tuple, int] = {}
    counts: dict[str, int] = {}
    current: tuple = ()
    for no, line in enumerate(text.splitlines(), start=1):
        header = _HEADER.match(line)
        if header:
            name = tuple(part.strip().strip("\"'") for part in header.group(2).split("."))
            if header.group(1) == "[[":
                k = counts.get(".".join(name), 0)
                counts[".".join(name)] = k + 1
                current = name + (k,)
                lines.setdefault(name, no)
            else:
                current = name
            lines.setdefault(current, no)
            continue
        key = _KEY.match(line)
        if key:
            path = current + (key.group(1).strip("\"'"),)
            lines.setdefault(path, no)
            for inner in re.finditer(r"[{,]\s*([A-Za-z0-9_\-]+)\s*=", line[key.end():]):
                lines.setdefault(path + (inner.group(1),), no)
    return lines


