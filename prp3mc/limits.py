"""What a request needs in memory before it runs, and the refusal of what will not fit.

Every command sizes its request here first and calls :func:`check`, which
refuses, in one line giving the byte count and the limit, a request that
needs more than :data:`MEMORY_MARGIN` of the memory this machine has
available. The byte counts follow the data the analyses hold at their peak
(rough on purpose, within a factor of about two), not any machine's speed:
each analysis' memory model lives in one function below, so a change of the
code's layout is one line here.

Time is not estimated (a throughput measured on one machine is wrong on the
next): ``prp3mc --max-hours H`` stops a run after H hours of wall time, and
it unwinds as after Ctrl-C, leaving no half-written folder (:mod:`prp3mc.cli`).
"""

from __future__ import annotations

import math

import os
from dataclasses import dataclass
from pathlib import Path

from ._threads import cores
from .errors import ResourceError

#: Default bound of the exact yield's absolute error of every probability: 1e-9 (1e-3 ppm). Here, not in
#: prp3mc.stackup, so that ``prp3mc yield --help`` reads it without importing numba.
DEFAULT_TARGET = 1e-9
#: The exact yield's targets taken: below 1e-12 the floating-point share of the bound (1e-13 per coefficient)
#: alone exceeds the target (the paper's budget: 4e-12 at 1e-12, so the bound misses it with a warning); above
#: 1e-2 it bounds nothing a yield needs.
TARGET_RANGE = (1e-12, 1e-2)

__all__ = ["DEFAULT_TARGET", "TARGET_RANGE", "CONDITIONED_THREAD_BYTES", "Estimate", "available_memory", "check",
           "montecarlo_estimate", "sobol_estimate", "worstcase_estimate", "allocate_estimate", "study_estimate",
           "discrepancy_estimate", "simulate_estimate", "sensitivity_estimate", "yield_estimate", "plan_estimate",
           "format_bytes", "format_seconds", "MEMORY_MARGIN"]

#: Share of the available memory a request may use.
MEMORY_MARGIN = 0.8

# Monte Carlo streams its samples in blocks of 65536 (prp3mc.montecarlo._stream): what still grows
# with n is the float32 pilot (n / 1024 samples of f features), the per-segment feature sums
# (S1, S2: f + f^2 float64 per block) and, per pose, one position sum per segment (a block or one
# of the 64 batches) besides the pose's model and results; the order statistics of a chunk of
# poses take at most _MC_CHUNK_BYTES, plus the blocks in flight.
_MC_BYTES_PER_SAMPLE = lambda d, f: 4 * f / 1024 + 8 * f * (f + 1) / 65536  # noqa: E731
_MC_BYTES_PER_SAMPLE_POSE = 8 / 65536
_MC_BYTES_PER_POSE = lambda f: 8 * 64 + 1000 + 40 * f  # noqa: E731
_MC_CHUNK_BYTES = 256 << 20
# Sobol: the design and its features for (K + 2) N model runs, and per pose in flight the outputs of
# every run; the Shapley effects' draws (3 d runs per order) and their latent normals.
# Exact worst case: the kept linear model and term bounds per pose (601^2 poses held 331 MiB).
_WC_BYTES_PER_POSE_TERM = 100
_WC_BYTES_PER_POSE = 200
# What a study keeps of each configuration's worst case, per pose: the poses, both maxima and the term bounds
# (618 B traced per pose at 10^4 poses with the paper's 12 inputs).
def _wc_held_bytes_per_pose(d: int) -> int:
    return 400 + 20 * d
# Exact yield: per pose the linear model's columns, each channel's lattice and results (2.0 KiB per pose at
# 900 poses with an orientation spec, traced), and the table's row as text or as a JSON object.
_YIELD_BYTES_PER_POSE = 4096
#: Bytes each thread of the exact yield's P(either) by conditioning on two legs (prp3mc.stackup.conditional) holds
#: at most: its chunk of poses is sized to it (the legs' CDF bounds and the cells of every pose; one pose's CDFs
#: computed at a time; at least one pose, which fits at the largest grid, 2^19 points a leg).
CONDITIONED_THREAD_BYTES = 192 << 20
# A study keeps, per configuration, the pose errors of every Monte Carlo draw at its histograms' poses
# (position and |dphi|, float64) for the report's figures.
_STUDY_BYTES_PER_HISTOGRAM_SAMPLE = 2 * 8
# Discrepancy workflow: the parametric bootstrap of the tests
# holds every replicate's samples, features and whitened errors of every row (8 (2d + 8) bytes per
# replicate, row); the spatial test a few dense (3P)^2 matrices and their product; ISO 9283's predicted
# figures n_mc simulated campaigns of the most visited pose; a report reads the rows and draws them.
_DISC_BYTES_PER_REPLICATE_ROW = lambda d: 8 * (2 * d + 8)  # noqa: E731
_DISC_BYTES_SPATIAL = 6 * 8                 # per (3P)^2
_DISC_BYTES_ISO_VISIT = 100                 # per simulated campaign and visit of the most visited pose
_DISC_BYTES_FIXED = 64 << 20
# Simulated campaign: per measurement its drawn inputs, the exact chain's pose, the table's row and its
# CSV text (180000 rows held 1.3 KiB each at the peak).
_SIM_BYTES_PER_MEASUREMENT = 2048
# Campaign plan: per candidate pose and visit its approach directions, the effects' signatures and their
# information, the planned and reference campaigns (0.63 KiB with one effect, 1.7 KiB with seven, traced at
# 405 candidates x 100 visits).
_PLAN_BYTES_PER_CANDIDATE_VISIT = lambda n_effects: 512 + 192 * n_effects  # noqa: E731
# Sensitivity over a grid: every matrix entry of every pose as a row of the long table and its CSV text
# (3600 poses held 27 KiB each).
_SENS_BYTES_PER_POSE = 32 << 10


@dataclass(frozen=True, slots=True)
class Estimate:
    """What a request needs: peak memory in bytes."""

    what: str
    bytes: float
    #: How to make the request smaller, for the refusal.
    hint: str = "use fewer samples or poses"

    def then(self, other: "Estimate") -> "Estimate":
        """This request followed by ``other``: the larger memory."""
        return Estimate(f"{self.what}, {other.what}", max(self.bytes, other.bytes), self.hint)


def format_bytes(n: float) -> str:
    """``n`` bytes in binary units, e.g. ``87 TiB``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"):
        if n < 1024 or unit == "EiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    raise AssertionError("unreachable")


def format_seconds(s: float) -> str:
    """A duration in the largest fitting unit, e.g. ``3.2 days``."""
    for unit, size in (("years", 365.25 * 86400), ("days", 86400), ("h", 3600), ("min", 60)):
        if s >= size:
            text = f"{s / size:.3g}"
            return f"{text} {unit[:-1] if text == '1' and unit.endswith('s') else unit}"
    return f"{s:.2g} s"


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_available() -> int | None:
    """Room left under a cgroup v2 memory limit (containers), if there is one."""
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = int(Path("/sys/fs/cgroup/memory.current").read_text())
    except (OSError, ValueError):
        return None
    return None if limit == "max" else max(0, int(limit) - used)


def available_memory() -> int:
    """Bytes of memory available to a new request (``MemAvailable``, a cgroup limit, or free pages)."""
    candidates = [m for m in (_meminfo_available(), _cgroup_available()) if m is not None]
    if not candidates:
        try:
            candidates.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
            return 1 << 62
    return min(candidates)


def check(estimate: Estimate, *, memory: int | None = None) -> Estimate:
    """Refuse ``estimate`` if it needs more than the memory available.

    Parameters
    ----------
    estimate : Estimate
    memory : int, optional
        Available bytes (default :func:`available_memory`); the request may
        use :data:`MEMORY_MARGIN` of it.

    Raises
    ------
    ResourceError
        One line with the estimate and the limit.
    """
    memory = available_memory() if memory is None else memory
    if not estimate.bytes <= MEMORY_MARGIN * memory:
        raise ResourceError(f"{estimate.what} needs ~{format_bytes(estimate.bytes)} of memory, this machine has "
                            f"{format_bytes(memory)} available (limit {format_bytes(MEMORY_MARGIN * memory)}): "
                            f"{estimate.hint}")
    return estimate


def montecarlo_estimate(n_samples: int, n_poses: int, n_inputs: int, workers: int | None = None) -> Estimate:
    """Memory of :func:`prp3mc.montecarlo.propagation.monte_carlo` (features ~ inputs)."""
    n, d = float(n_samples), n_inputs
    workers = workers or cores()
    return Estimate(f"Monte Carlo of {n_samples} samples at {n_poses} pose(s)",
                    n * _MC_BYTES_PER_SAMPLE(d, d) + n * n_poses * _MC_BYTES_PER_SAMPLE_POSE
                    + n_poses * _MC_BYTES_PER_POSE(d) + _MC_CHUNK_BYTES + workers * 16 * d * 65536)


def sobol_estimate(n_samples: int, n_poses: int, n_inputs: int, n_factors: int, n_outputs: int,
                   shapley_permutations: int = 0) -> Estimate:
    """Memory of :func:`prp3mc.sobol.indices.sobol_indices` (N base samples, K factors, and the Shapley
    effects' 3 d runs per random order)."""
    n, runs = float(n_samples), float(n_samples) * (n_factors + 2)
    shapley = 3.0 * n_inputs * shapley_permutations
    per_pose = 8 * (runs + shapley) * 3 * (1 + n_outputs)
    memory = (runs + 2 * shapley) * 16 * n_inputs + min(n_poses, 4) * per_pose
    return Estimate(f"Sobol indices of N = {n_samples} at {n_poses} pose(s)", memory)


def worstcase_estimate(n_poses: int, n_inputs: int) -> Estimate:
    """Memory of :func:`prp3mc.worstcase.envelope.worst_case` over ``n_poses`` poses."""
    n = float(n_poses)
    return Estimate(f"exact worst case at {n_poses} poses",
                    n * (_WC_BYTES_PER_POSE + _WC_BYTES_PER_POSE_TERM * n_inputs), "use fewer poses")


def yield_estimate(n_poses: int, conditioned: bool = False, workers: int | None = None) -> Estimate:
    """Memory of :func:`prp3mc.stackup.exceedance.exact_yield` over ``n_poses`` poses and its table.

    ``conditioned``: with an orientation spec, P(either) may be found by conditioning on two legs
    (:mod:`prp3mc.stackup.conditional`), whose threads (one per core, at most one per pose) hold
    :data:`CONDITIONED_THREAD_BYTES` each at most.
    """
    memory = float(n_poses) * _YIELD_BYTES_PER_POSE
    if conditioned:
        memory += min(workers or cores(), max(n_poses, 1)) * float(CONDITIONED_THREAD_BYTES)
    return Estimate(f"exact yield at {n_poses} poses", memory, "use fewer poses")


def allocate_estimate(n_poses: int, n_inputs: int, n_samples: int = 0) -> Estimate:
    """Memory of :func:`prp3mc.allocation.optimum.allocate` over ``n_poses`` poses.

    ``n_samples`` > 0 adds the Monte Carlo confirmation of a percentile spec.
    """
    wc = worstcase_estimate(n_poses, n_inputs)
    total = Estimate(f"tolerance allocation over {n_poses} poses", wc.bytes)
    return total.then(montecarlo_estimate(n_samples, 1, n_inputs)) if n_samples else total


def study_estimate(study) -> Estimate:
    """Memory of running a :class:`prp3mc.study.Study`: what its configurations keep to the report, plus the
    largest analysis of one configuration.

    A configuration's analyses run one after another (worst case, Monte Carlo and its draws at the
    histograms' poses, exact yield, Sobol, allocation: the largest counts), while every configuration run
    before it keeps its worst case and its histograms' draws: those are added to that analysis, not compared
    with the memory on their own.
    """
    d = len(study.budget.factors)
    variants = math.prod(len(entry[-1]) for entry in getattr(study, "sweep", ()))   # of each configuration
    n_conf = len(study.configurations) * variants
    wc_poses = study.worstcase_grid[0] * study.worstcase_grid[1]
    held = Estimate(f"the worst cases at {n_conf * wc_poses} poses", n_conf * wc_poses * _wc_held_bytes_per_pose(d))
    stage = Estimate("", 0.0).then(worstcase_estimate(wc_poses, d))
    mc_poses = study.mc_grid[0] * study.mc_grid[1]
    if "montecarlo" in study.outputs:
        per_configuration = [3 if c.poses is None else len(c.poses) for c in study.configurations]
        histogram_poses = variants * sum(per_configuration)
        kept = Estimate(f"Monte Carlo draws at {histogram_poses} histogram poses",
                        histogram_poses * float(study.mc_samples) * _STUDY_BYTES_PER_HISTOGRAM_SAMPLE)
        held = Estimate(f"{held.what}, {kept.what}", held.bytes + kept.bytes)
        # after the streamed run: the budget's draws and their pose errors at one configuration's histogram poses
        draws = float(study.mc_samples) * 8 * (d + 3 * max(per_configuration))
        stage = stage.then(montecarlo_estimate(study.mc_samples, mc_poses, d)).then(
            Estimate(f"{study.mc_samples} draws of {d} inputs", draws))
    if study.spec is not None and "yield" in study.outputs:
        stage = stage.then(yield_estimate(mc_poses, conditioned=study.spec.phi_arcsec is not None))
    if "sobol" in study.outputs:
        n_poses = study.sobol_grid[0] * study.sobol_grid[1]
        stage = stage.then(sobol_estimate(study.sobol_samples, n_poses, d,
                                          d + len(study.budget.groups) + len(study.sobol_groups),
                                          len(study.sobol_outputs), shapley_permutations=study.sobol_samples // 2))
    allocation = getattr(study, "allocation", None)
    if allocation is not None:
        nx, ny = allocation.grid or study.worstcase_grid
        stage = stage.then(allocate_estimate(nx * ny, len(allocation.classes.inputs) + d, allocation.samples
                                             if allocation.spec_percentile is not None else 0))
    return Estimate(f"study {study.name!r} (kept: {held.what}; with the largest analysis of a configuration: "
                    f"{stage.what.removeprefix(', ')})", held.bytes + stage.bytes)


def sensitivity_estimate(n_poses: int) -> Estimate:
    """Memory of ``prp3mc sensitivity --region`` at ``n_poses`` poses (A, B and every J_q as a long table)."""
    return Estimate(f"sensitivity matrices at {n_poses} poses", float(n_poses) * _SENS_BYTES_PER_POSE,
                    "use a smaller --grid")


def simulate_estimate(n_measurements: int) -> Estimate:
    """Memory of :func:`prp3mc.measurement.campaign.simulate.simulate_campaign` and its CSV (``n_measurements`` rows)."""
    return Estimate(f"a simulated campaign of {n_measurements} measurements",
                    float(n_measurements) * _SIM_BYTES_PER_MEASUREMENT, "use fewer poses or visits")


def plan_estimate(n_candidates: int, n_visits: int, n_effects: int) -> Estimate:
    """Memory of :func:`prp3mc.measurement.campaign.plan.plan_campaign` (``n_candidates`` poses to choose from)."""
    return Estimate(f"a campaign plan of {n_visits} visits of {n_candidates} candidate poses",
                    float(n_candidates) * n_visits * _PLAN_BYTES_PER_CANDIDATE_VISIT(n_effects), "use fewer visits")


def discrepancy_estimate(n_measurements: int, n_poses: int | None = None, max_visits: int | None = None,
                         n_inputs: int = 12, n_bootstrap: int = 400, n_mc: int = 4000) -> Estimate:
    """Memory of :func:`prp3mc.measurement.discrepancy.workflow.discrepancy` and its report.

    Parameters
    ----------
    n_measurements : int
        Rows of the campaign.
    n_poses, max_visits : int, optional
        Distinct poses, and rows of the most visited one. Unknown (None)
        before the file is read: the estimate from the row count alone is
        then a lower bound.
    n_inputs : int
        Inputs of the budget.
    n_bootstrap, n_mc : int
        Bootstrap replicates of the tests, simulated campaigns of ISO 9283's predicted figures.
    """
    m, p, visits = float(n_measurements), float(n_poses or 0), float(max_visits or 1)
    poses = f" of {n_poses} poses" if n_poses else ""
    return Estimate(f"discrepancy analysis of {n_measurements} measurements{poses}",
                    n_bootstrap * m * _DISC_BYTES_PER_REPLICATE_ROW(n_inputs) + _DISC_BYTES_SPATIAL * (3 * p) ** 2
                    + _DISC_BYTES_ISO_VISIT * n_mc * visits + _DISC_BYTES_FIXED,
                    "split the campaign into smaller ones (fewer rows or poses)")
