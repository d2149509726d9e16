"""Benchmark of design sweeps: configurations per second in one process and on Dask workers.

Runs the bundled ``sweep_example`` study, its sweep widened to 4 x 4 = 16
feasible configurations (``--quick``: 2 x 2), in this process and on a Dask
LocalCluster of 1 and 2 worker processes (one thread each; the cluster's
start-up is timed apart). Measures the per-configuration cost, the pickled
size of a task's inputs and of its result, the unpickling time of a result on
the client, and the scheduler's round trip of an empty task; from them it
estimates the throughput of a 100-worker cluster and what limits it.

Usage: ``python benchmarks/bench_sweep.py [--quick]`` prints one JSON object.
Needs ``pip install 'prp3mc[dask]'``.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import time
from dataclasses import replace

from prp3mc.study.distributed import DaskExecutor
from prp3mc.study.reader import Study
from prp3mc.study.runner import Plan, run_configuration, run_study
from prp3mc.study.sweep import expand

#: Assumed network bandwidth into the client of a real cluster (10 Gbit/s Ethernet), bytes/s.
BANDWIDTH = 1.25e9


def _noop(k: int) -> int:
    return k


def _study(quick: bool) -> Study:
    values = ((180, 220), (10, 20)) if quick else ((180, 200, 220, 240), (10, 15, 20, 25))
    study = Study.load("sweep_example")
    return replace(study, sweep=(("leg.3.a_mm", values[0]), ("leg.*.e_mm", values[1])))


def _load() -> float:
    return os.getloadavg()[0]


def bench_sweep(quick: bool) -> dict:
    study = _study(quick)
    variants = expand(study)
    n = len(variants)
    out: dict = {"configurations": n, "cores": os.cpu_count(), "load_1min_before": _load()}
    one = replace(study, sweep=(("leg.3.a_mm", (180,)),))
    run_study(one, progress=False)  # warm-up (imports, caches)

    t0 = time.perf_counter()
    serial = run_study(study, progress=False)
    t = time.perf_counter() - t0
    assert len(serial.configurations) == n, serial.skipped
    out.update(serial_seconds=t, serial_configurations_per_s=n / t, seconds_per_configuration=t / n,
               timings_s={k: v / n for k, v in serial.timings_s.items()})

    plan = Plan(replace(study, configurations=()), serial.montecarlo_seed, serial.sobol_seed, n)
    task = pickle.dumps((plan, variants[0]))
    outcome = run_configuration(plan, variants[0])
    result = pickle.dumps(outcome)
    t_loads = min(_timed(lambda: pickle.loads(result)) for _ in range(5))
    out.update(task_bytes=len(task), result_bytes=len(result), result_unpickle_seconds=t_loads,
               result_samples_bytes=len(pickle.dumps(outcome.result.samples)))

    for workers in (1, 2):
        t0 = time.perf_counter()
        with DaskExecutor(f"local:{workers}") as executor:
            startup = time.perf_counter() - t0
            run_study(one, progress=False, scheduler=executor)  # warm-up: workers import prp3mc
            t0 = time.perf_counter()
            on_dask = run_study(study, progress=False, scheduler=executor)
            t = time.perf_counter() - t0
            assert len(on_dask.configurations) == n
            out[f"dask_{workers}_startup_seconds"] = startup
            out[f"dask_{workers}_seconds"] = t
            out[f"dask_{workers}_configurations_per_s"] = n / t
            if workers == 2:
                k = 200 if quick else 1000
                client = executor.client
                t0 = time.perf_counter()
                client.gather(client.map(_noop, range(k), pure=False))
                out["scheduler_seconds_per_empty_task"] = (time.perf_counter() - t0) / k
    out["load_1min_after"] = _load()

    # a 100-worker cluster: compute, the scheduler and the client's gathering, whichever is slowest
    per_task = out["scheduler_seconds_per_empty_task"]
    gather = out["result_bytes"] / BANDWIDTH + t_loads
    limits = {"compute": 100 / out["seconds_per_configuration"], "scheduler": 1 / per_task,
              "gathering": 1 / gather}
    out["estimate_100_workers"] = {"configurations_per_s": min(limits.values()),
                                   "limit": min(limits, key=limits.get),
                                   "limits_configurations_per_s": limits,
                                   "client_memory_bytes_per_1000_configurations": 1000 * out["result_bytes"],
                                   "assumed_bandwidth_bytes_per_s": BANDWIDTH}
    return out


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 x 2 configurations, fewer empty tasks")
    print(json.dumps(bench_sweep(parser.parse_args().quick), indent=1))
