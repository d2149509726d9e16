"""The exact yield's lattice walk, stage by stage, on a grid of poses (CPU time, one thread).

Captures the per-pose arguments the grid path hands to :func:`prp3mc.stackup.series.batch_series`
(P(position > S), paper budget, U-shape, 21 x 21 grid by default), then times with ``time.process_time``
(best of ``--repeat``), each over every pose in one compiled loop:

- ``legs``: the basis legs' 1-D envelope arrays (:func:`~prp3mc.stackup.truncation.leg_envelope`, ending
  where :func:`~prp3mc.stackup.truncation.select_points` ends them);
- ``select``: :func:`~prp3mc.stackup.truncation.select_points` whole (arrays, row bounds, walk, drop);
- ``series``: :func:`~prp3mc.stackup.series.pose_series` whole (select_points and the sum over the kept points).

It prints one JSON object (ms a pose, points walked and kept a pose, the 1-minute load), and with
``--save FILE`` writes each pose's bound, points walked and kept, P and its bound (``.npz``) for comparing
two trees. Run it under each tree's ``PYTHONPATH`` in turn to compare them in one run. Usage:
``NUMBA_NUM_THREADS=1 python benchmarks/bench_yield_walk.py [--n 21] [--geometry u-shape] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from numba import njit

from prp3mc import Budget, Geometry, Region, exact_yield
from prp3mc.stackup import exceedance
from prp3mc.stackup.series import pose_series
from prp3mc.stackup.truncation import arrays_end, leg_envelope, select_points


def capture(geometry: str, n: int, s_um: float) -> tuple:
    """The arguments of the grid's batch_series call for the position channel."""
    seen = []
    original = exceedance.batch_series

    def spy(*args):
        seen.append(args)
        return original(*args)

    exceedance.batch_series = spy
    try:
        exact_yield(Geometry.from_preset(geometry), Budget.from_preset("paper"), Region.from_preset(geometry).grid(n),
                    spec_position_um=s_um, quantiles=False, workers=1)
    finally:
        exceedance.batch_series = original
    return next(a for a in seen if a[2] == 2)[2:]


@njit
def _legs(d, ev, grp, mu, Q, mnorm, lam, z1, z2, eps):
    s = 0.0
    for i in range(grp.shape[0]):
        g0 = (z1[i] * z1[i] * np.pi / lam[i]) ** 0.5        # select_points' g at the origin (d = 2: the disc)
        for j in range(d):
            s += leg_envelope(j, d, ev, grp[i], mu[i], Q[i], mnorm[i], lam[i], z1[i], z2[i], g0, arrays_end(d, eps))[4]
    return s


@njit
def _select(d, ev, grp, mu, Q, Vinv, mnorm, ab, lam, z1, z2, eps, out_b, out_n, out_k):
    for i in range(grp.shape[0]):
        pts, out_b[i], out_n[i], _ = select_points(d, ev, grp[i], mu[i], Q[i], Vinv[i], mnorm[i], ab[i], lam[i], z1[i],
                                                   z2[i], eps)
        out_k[i] = pts.shape[0]


@njit
def _series(d, kind, par, ev, tab, sp, grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs, eps, alias, out_p, out_b):
    lev = np.empty(0)
    q = np.empty(0)
    for i in range(grp.shape[0]):
        out_p[i], out_b[i], _, _ = pose_series(d, kind, par, ev, tab, sp, grp[i], mu[i], snu[i], Q[i], Vinv[i],
                                               mnorm[i], ab[i], lam[i], z1[i], z2[i], zs[i], eps, alias[i], lev,
                                               np.empty(0), 1.0, q, q)


def best(fn, repeat: int) -> float:
    t = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        fn()
        t = min(t, time.process_time() - c0)
    return t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=21)
    ap.add_argument("--geometry", default="u-shape")
    ap.add_argument("--spec-um", type=float, default=100.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--save", default=None)
    ap.add_argument("--select-only", action="store_true", help="time select_points alone")
    args = ap.parse_args()
    (d, kind, par, ev, tab, sp, grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs, eps, alias, levels, z0, zmax, ok,
     *_) = capture(args.geometry, args.n, args.spec_um)
    sel = ok
    grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs, alias = (np.ascontiguousarray(a[sel]) for a in
                                                                (grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs,
                                                                 alias))
    N = grp.shape[0]
    b, nw, nk = np.empty(N), np.empty(N, np.int64), np.empty(N, np.int64)
    p, bp = np.empty(N), np.empty(N)
    _legs(d, ev, grp[:1], mu[:1], Q[:1], mnorm[:1], lam[:1], z1[:1], z2[:1], eps)
    _select(d, ev, grp, mu, Q, Vinv, mnorm, ab, lam, z1, z2, eps, b, nw, nk)
    _series(d, kind, par, ev, tab, sp, grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs, eps, alias, p, bp)
    load0 = os.getloadavg()[0]
    t_legs = best(lambda: _legs(d, ev, grp, mu, Q, mnorm, lam, z1, z2, eps), args.repeat)
    t_sel = best(lambda: _select(d, ev, grp, mu, Q, Vinv, mnorm, ab, lam, z1, z2, eps, b, nw, nk), args.repeat)
    t_ser = np.nan if args.select_only else best(lambda: _series(d, kind, par, ev, tab, sp, grp, mu, snu, Q, Vinv, mnorm, ab, lam, z1, z2, zs, eps,
                                 alias, p, bp), args.repeat)
    out = {"tree": os.path.dirname(os.path.dirname(exceedance.__file__)), "poses": N,
           "legs_ms": 1e3 * t_legs / N, "select_ms": 1e3 * t_sel / N, "series_ms": 1e3 * t_ser / N,
           "sum_ms": 1e3 * (t_ser - t_sel) / N, "walked": float(nw.mean()), "kept": float(nk.mean()),
           "bound_max": float(b.max()), "load": [load0, os.getloadavg()[0]]}
    if args.save:
        np.savez(args.save, bound=b, walked=nw, kept=nk, p=p, bp=bp)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
