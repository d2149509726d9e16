"""The memory checks count what is held together: a study's kept results with its largest analysis, an
allocation's terms from its menu (prp3mc.limits)."""

import pytest

from prp3mc.cli import main
from prp3mc.errors import ResourceError
from prp3mc.limits import allocate_estimate, sobol_estimate, study_estimate
from prp3mc.study.reader import Study

from .test_allocation_memory import FAMILIES

SWEEP = """\
name = "held"
seed = 1
outputs = ["montecarlo", "sobol"]
[worstcase]
grid = 3
[montecarlo]
samples = 262144
grid = 2
[sobol]
samples = 65536
grid = 2
[[configuration]]
geometry = "u-shape"
[sweep]
"leg.3.a_mm" = [{values}]
"""


def test_a_study_counts_its_kept_draws_with_its_largest_analysis():
    """Every configuration keeps its Monte Carlo draws at three histogram poses (position and |dphi|, float64)
    to the report, so the last configuration's Sobol run has them all beside it: the estimate is at least their
    sum. It was the larger of the two (the Sobol run compared with the memory on its own)."""
    n_conf = 40
    study = Study.from_text(SWEEP.format(values=", ".join(f"{200 + k / 10:g}" for k in range(n_conf))))
    d = len(study.budget.factors)
    kept = n_conf * 3 * study.mc_samples * 2 * 8
    sobol = sobol_estimate(study.sobol_samples, 4, d, d + len(study.budget.groups), len(study.sobol_outputs),
                           shapley_permutations=study.sobol_samples // 2).bytes
    assert min(kept, sobol) > 0.3 * max(kept, sobol)            # neither hides the other: the test can tell
    assert study_estimate(study).bytes >= kept + sobol


def test_allocate_sizes_its_worst_case_by_the_menus_inputs(tmp_path, monkeypatch, capsys):
    """``prp3mc allocate`` sized the worst case of every candidate with 12 inputs whatever the menu: 27 for a
    menu of nine families, so a grid of twice the memory passed the check."""
    import prp3mc.cli.allocate as allocate_cli

    path = tmp_path / "big.toml"
    path.write_text("".join(f'[{f}]\nclasses = [{{ name = "k", law = "uniform", lo = 0, hi = 0.001, cost = 1 }}]\n'
                            for f in FAMILIES))
    seen = []

    def record(args, estimate):
        seen.append(estimate)
        raise ResourceError("recorded")

    monkeypatch.setattr(allocate_cli, "within_limits", record)
    assert main(["allocate", "--geometry", "u-shape", "--region", "u-shape", "--classes", str(path),
                 "--spec-position-um", "30", "--grid", "100"]) == 1
    assert "recorded" in capsys.readouterr().err
    assert seen[0].bytes >= allocate_estimate(100 ** 2, 27).bytes


def test_simulate_sizes_a_plan_before_reading_it(tmp_path, monkeypatch, capsys):
    """``prp3mc simulate --plan FILE`` read the whole CSV and then sized it: a file too large for the memory
    was parsed first. Its rows are now counted without parsing (as ``discrepancy`` does) and refused before."""
    import pandas as pd

    plan = tmp_path / "plan.csv"
    plan.write_text("pose_id,x_cmd,y_cmd,phi_cmd\n" + "p,0,100,0\n" * 1000)

    def read_csv(*args, **kwargs):
        raise AssertionError("the plan was read before it was sized")

    monkeypatch.setattr(pd, "read_csv", read_csv)
    assert main(["--max-gb", "0.001", "simulate", "--geometry", "u-shape", "--budget", "paper", "--seed", "1",
                 "--plan", str(plan), "--out", str(tmp_path / "c.csv")]) == 1
    err = capsys.readouterr().err
    assert "a simulated campaign of 1000 measurements needs" in err and "more than --max-gb" in err


def test_conditioning_on_two_legs_stays_within_its_estimate():
    """P(either) by conditioning on two legs held every pose's CDF grids, Fourier coefficients and cells of a
    chunk of 8 at once (135 MiB traced on the paper's budget, ~1 GB with 2^19-point grids) and limits' yield
    estimate did not count it. One chunk's traced peak now lies below the model its chunks are sized by
    (chunk_bytes, an upper bound: at most 4 x _MAX_CELLS cells a pose) and above a fifth of it, at specs where
    every pose refines up to its cell budget; a thread's chunk fits CONDITIONED_THREAD_BYTES, one pose at the
    largest grid included, and the estimate with an orientation spec counts a thread per core."""
    import tracemalloc

    import numpy as np

    from prp3mc.limits import CONDITIONED_THREAD_BYTES, yield_estimate
    from prp3mc.stackup import conditional

    from .test_conditional import paper_legs

    poses = np.array([[-20.0, 80.0, 2.0], [15.0, 110.0, -3.0]])
    args = paper_legs(poses, 80.0, 30.0)
    conditional.joint_exceedance(*(a[:1] if k in (0, 1, 4) else a for k, a in enumerate(args)), workers=1)  # warm
    tracemalloc.start()
    J_lo, J_hi = conditional.joint_exceedance(*args, workers=1)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    model = conditional.chunk_bytes(len(poses), 1 << 16)
    print(f"traced peak {peak / 2 ** 20:.1f} MiB, model {model / 2 ** 20:.1f} MiB ({peak / model:.2f})")
    assert 0.2 * model < peak < model
    assert np.all(J_hi - J_lo > 1e-6)                   # the bracket refined up to its cell budget
    assert conditional.chunk_bytes(1, 2 * conditional._K_MAX) <= CONDITIONED_THREAD_BYTES
    plain, joint = yield_estimate(441).bytes, yield_estimate(441, conditioned=True, workers=2).bytes
    assert joint - plain == 2 * CONDITIONED_THREAD_BYTES
    assert yield_estimate(1, conditioned=True, workers=2).bytes < joint - plain     # one pose, one thread


def test_prp3mc_yield_refuses_by_bytes_the_conditioning_that_would_not_fit(capsys):
    """With an orientation spec the conditioning's threads are counted: refused in one line under --max-gb."""
    assert main(["--max-gb", "0.1", "yield", "--geometry", "u-shape", "--budget", "paper", "--region", "u-shape",
                 "--grid", "3", "--spec-position-um", "100", "--spec-phi-arcsec", "60"]) == 1
    err = capsys.readouterr().err.strip()
    assert "exact yield at 9 poses needs" in err and "more than --max-gb" in err and "\n" not in err
