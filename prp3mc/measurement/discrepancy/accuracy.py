"""Predicted accuracy of the measured machine: the original model, the updated one, and after compensation.

The source paper asks how accurate a manipulator is once a controller has
compensated what it can; a discrepancy analysis answers it for the machine
actually measured. Over the geometry's region (its preset region when the
geometry is a reference one; otherwise the campaign's pose hull, the
rectangle spanned by its commanded x and y at its median phi, keeping the
reachable poses) on a :data:`GRID` x :data:`GRID` grid, three models are
propagated with the analyses that understand a budget's ``[effects]``:

- **original**: the geometry and budget the campaign was analysed with;
- **updated**: the identified geometry and the updated budget (fitted
  spreads as laws, every systematic effect in ``[effects]``: offsets and
  scales shift the pose error, a backlash enters as ±h/2 and thermal
  expansion over its temperature range, their drivers being unknown at a
  pose of the region);
- **compensated**: the identified geometry and the compensated budget.

Each gives the exact worst case and Monte Carlo p95 and p99 of the position
error and of ``|dphi|``, each the largest over the grid (the three Monte Carlo
runs share their seed, so models that differ in their names only, as all
three do when nothing was named, are computed once).
"""

from __future__ import annotations

import numpy as np

from ..._rng import child_seed
from ..._threads import check_stop
from ...kinematics.chain import feasible
from ...kinematics.geometry import REGION_PRESETS, Geometry, Region
from ...model.budget import Budget
from ..campaign.data import Campaign
from .updated import UpdatedModel, base_name

__all__ = ["predicted_accuracy", "accuracy_region", "GRID", "N_SAMPLES", "MODELS"]

#: Grid points per side of the region (7 x 7 keeps the three models' Monte Carlo short; on the u-shape
#: region its maxima were within 1 % of an 11 x 11 grid's with 16384 samples).
GRID = 7
#: Monte Carlo samples per model (shared by the grid's poses).
N_SAMPLES = 1 << 13
#: The three models compared, in order.
MODELS = ("original", "updated", "compensated")
_STREAM_MC = 5


def accuracy_region(geometry: Geometry, campaign: Campaign) -> tuple[Region, str]:
    """The region the accuracy is predicted over, and where it comes from (see the module notes)."""
    name = base_name(geometry.name)
    if name in REGION_PRESETS:
        return Region.from_preset(name), f"the region of preset {name}"
    lo, hi = campaign.poses[:, :2].min(axis=0), campaign.poses[:, :2].max(axis=0)
    hi = np.where(hi > lo, hi, lo + 1e-3)
    phi = float(np.median(campaign.poses[:, 2]))
    return (Region((lo[0], hi[0]), (lo[1], hi[1]), phi),
            "the campaign's pose hull (its commanded x and y range at its median phi, reachable poses)")


def load_propagation() -> tuple:
    """:func:`~prp3mc.montecarlo.propagation.monte_carlo` and :func:`~prp3mc.worstcase.envelope.worst_case`,
    imported on first use: numba, which they load, serves this stage only."""
    from ...montecarlo.propagation import monte_carlo
    from ...worstcase.envelope import worst_case
    return monte_carlo, worst_case


def predicted_accuracy(geometry: Geometry, budget: Budget, model: UpdatedModel, campaign: Campaign, seed: int, *,
                       grid: int = GRID, n_samples: int = N_SAMPLES) -> dict:
    """Worst case and Monte Carlo percentiles over the region, three ways (see the module notes).

    Parameters
    ----------
    geometry, budget
        The original model (what the campaign was analysed with).
    model : UpdatedModel
    campaign : Campaign
    seed : int
        The Monte Carlo runs draw from a child stream of it.
    grid, n_samples : int

    Returns
    -------
    dict
        ``region`` (``x_mm, y_mm, phi_deg, grid, n_poses, source``),
        ``n_samples``, ``seed``, and per model of :data:`MODELS` its
        ``geometry`` and ``budget`` names, ``worst_case_position_mm``,
        ``worst_case_phi_deg``, ``p95_position_mm``, ``p99_position_mm``,
        ``p95_phi_deg``, ``p99_phi_deg`` (largest over the region; phi of ``|dphi|``).
    """
    monte_carlo, worst_case = load_propagation()
    region, source = accuracy_region(geometry, campaign)
    poses = region.grid(grid).reshape(-1, 3)
    poses = poses[feasible(model.geometry, poses) & feasible(geometry, poses)]
    if not poses.size:                       # a hull whose grid misses the workspace: the campaign's own poses
        poses, source = campaign.poses, "the campaign's commanded poses"
    mc_seed = child_seed(seed, _STREAM_MC)
    out: dict = {"region": {"x_mm": list(region.x_mm), "y_mm": list(region.y_mm), "phi_deg": region.phi_deg,
                            "grid": grid, "n_poses": int(poses.shape[0]), "source": source},
                 "n_samples": n_samples, "seed": mc_seed}
    pairs = {"original": (geometry, budget), "updated": (model.geometry, model.budget),
             "compensated": (model.geometry, model.compensated)}
    figures: list = []                       # (what the analyses read of a model, its figures)
    for label, (g, b) in pairs.items():
        check_stop()                         # on a thread of its own (prp3mc.measurement.discrepancy.workflow)
        key = _content(g, b)
        known = next((f for k, f in figures if k == key), None)   # models that differ in names only: once
        if known is None:
            wc = worst_case(g, b, poses)     # the numpy path: at 49 poses it beats loading the fused kernel
            mc = monte_carlo(g, b, poses, n_samples, rng=mc_seed, percentiles=(95.0, 99.0), progress=False,
                             workers=1)
            known = {"worst_case_position_mm": float(wc.position_mm.max()),
                     "worst_case_phi_deg": float(wc.phi_deg.max()),
                     "p95_position_mm": float(mc.position_pct[:, 0].max()),
                     "p99_position_mm": float(mc.position_pct[:, 1].max()),
                     "p95_phi_deg": float(mc.phi_pct[:, 0].max()), "p99_phi_deg": float(mc.phi_pct[:, 1].max())}
            figures.append((key, known))
        out[label] = {"geometry": g.name, "budget": b.name, **known}
    return out


def _content(geometry: Geometry, budget: Budget) -> tuple:
    """What the worst case and the Monte Carlo read of a model: all but its names (and the budget's records)."""
    return geometry.replace(name=""), list(budget.inputs.items()), list(budget.effects.items())
