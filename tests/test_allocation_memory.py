"""The allocation search's queue is refused by its byte count: the count it uses is what the queue holds."""

import tracemalloc

import numpy as np
import pytest

from prp3mc import Geometry
from prp3mc.allocation import search as search_module
from prp3mc.allocation.classes import ClassMenu
from prp3mc.allocation.optimum import region_poses
from prp3mc.allocation.search import Problem, Search
from prp3mc.errors import ResourceError

FAMILIES = ("rho", "theta", "b", "a", "alpha", "beta", "c", "gamma", "psi")


def big_menu() -> ClassMenu:
    """27 inputs of six classes each (6^27 choices): nested clearances, and eight families of side-by-side
    intervals without a common one, which the search must branch before any bound prunes."""
    doc = {f: {"classes": [{"name": f"k{k}", "law": "uniform", "lo": (k - 3) * 1e-3, "hi": (k - 2) * 1e-3,
                            "cost": 6.0 - abs(k - 2.5)} for k in range(6)]} for f in FAMILIES[1:]}
    doc["rho"] = {"classes": [{"name": f"k{k}", "law": "uniform", "lo": 0.0, "hi": (k + 1) * 1e-3, "cost": 6.0 - k}
                              for k in range(6)]}
    return ClassMenu.from_dict(doc, source="27 inputs of six classes")


@pytest.mark.parametrize("search", ["least_cost", "closest"])
def test_queue_bytes_per_node_are_what_the_refusal_counts(search, monkeypatch):
    """Traced memory against queued nodes while the queue grows: its slope stays within the per-node count
    the refusal uses, and above half of it (a count far above the truth would refuse what fits)."""
    problem = Problem(Geometry.from_preset("u-shape"), big_menu(), region_poses("u-shape", grid=5))
    J = len(problem.inputs)
    per_node = search_module._node_bytes(J)
    seen = []
    over_limits = search_module._over_limits

    def record(s, queued):
        seen.append((queued, tracemalloc.get_traced_memory()[0]))
        over_limits(s, queued)

    monkeypatch.setattr(search_module, "_over_limits", record)
    monkeypatch.setattr(search_module, "available_memory", lambda: int(25_000 * per_node / search_module.MEMORY_MARGIN))
    s = Search(problem, {"position": 0.003})
    assert s.max_queued == 25_000
    tracemalloc.start()
    try:
        with pytest.raises(ResourceError, match="memory"):
            getattr(s, search)()
    finally:
        tracemalloc.stop()
    queued, traced = np.array(seen, dtype=float).T
    grown = queued > 5_000
    slope = np.polyfit(queued[grown], traced[grown], 1)[0]
    assert 0.5 * per_node < slope <= per_node, (slope, per_node)
    assert queued[-1] > s.max_queued >= queued[-2]     # refused at the first push past the limit, not later
