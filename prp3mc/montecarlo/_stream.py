"""Streamed Monte Carlo: sample blocks, moments by segments, exact order statistics in bounded memory.

Samples are the rows of ``budget.sample(n, seed)``, in blocks of
:data:`~prp3mc.model.budget.SAMPLE_BLOCK`; each thread takes a
contiguous range of blocks and starts its generator where that range starts
(a jump ahead in the seed's stream), so the samples do not depend on the
number of threads or the memory limit. When every law and feature has a
compiled form (:mod:`._sampler`) the samples are drawn tile by tile inside
the kernel and never held; otherwise block k is drawn through numpy
(:meth:`Budget.sample_block`) and handed to the same kernel.

Moments: sums of the features and of their cross products (about their exact
mean) per *segment*, the intersection of a sample block with one of the 64
batches; the batch and overall means and covariances follow from these sums.

Order statistics (exact, the same as sorting all n values): a pilot, the
first ``m`` samples, places a window ``[lo, hi)`` around each wanted rank
(the pilot's order statistics at the rank's quantile +- 5 pilot standard
errors). One streamed pass counts the values below each window and keeps the
values inside it; a rank whose window turns out to hold it is read off the
kept values by radix selection (:mod:`._select`). Otherwise (a pilot off by more than 5 standard
errors, or a window holding more values than its buffer) the next pass uses
a narrower window, known from that pass's exact counts and a 64-bin
histogram inside every window; windows shrink to a single float32 value at
worst, so the selection always ends with the exact order statistic.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ._kernel import SUB_BINS, TILE, feature_key, padded_features, pose_values, scan_blocks
from ._select import count_below, order_statistics
from ._sampler import LANES, draw_features, pcg_lanes, sampler_tables
from .._threads import check_stop
from ..model.budget import SAMPLE_BLOCK, Budget
from ..model.linear import LinearModel

__all__ = ["Stream", "Moments", "pilot_fraction", "select_order_statistics"]

_PILOT_SE = 5.0  # half-width of a pilot window, in pilot standard errors of the quantile
_F32_INF = np.float32(np.inf)
#: Sample blocks per compiled call of a worker's pass: between calls it sees a stop request (a fraction of a
#: second of work; the calls carry the sampler's state on, so the samples are those of one call).
STOP_BLOCKS = 16


@dataclass(frozen=True)
class Moments:
    """Feature sums per segment, reduced to batch and overall moments."""

    mean: np.ndarray  # (F,)
    cov: np.ndarray  # (F, F)
    batch_means: np.ndarray  # (B, F)
    batch_covs: np.ndarray  # (B, F, F)


class Stream:
    """The samples of one Monte Carlo run as independently drawable blocks.

    Parameters
    ----------
    model : LinearModel
    budget : Budget
    seed, n : int
        The run's seed and sample count.
    n_batches : int
        Batches for the batch-means standard errors.
    workers : int
        Threads; each takes a contiguous range of blocks.
    """

    def __init__(self, model: LinearModel, budget: Budget, seed: int, n: int, n_batches: int, workers: int):
        self.model, self.budget, self.seed, self.n = model, budget, seed, n
        self.n_blocks = -(-n // SAMPLE_BLOCK)
        self.batch_edges = np.linspace(0, n, n_batches + 1).astype(np.int64)
        cuts = np.union1d(self.batch_edges, np.arange(0, n, SAMPLE_BLOCK, dtype=np.int64))
        cuts = np.append(cuts[cuts < n], n)
        self.seg_start, self.seg_stop = cuts[:-1], cuts[1:]
        self.seg_batch = np.searchsorted(self.batch_edges, self.seg_start, side="right") - 1
        self.block_segs = np.searchsorted(self.seg_start, np.arange(self.n_blocks + 1) * SAMPLE_BLOCK)
        parts = np.array_split(np.arange(self.n_blocks), max(1, min(workers, self.n_blocks)))
        self.worker_blocks = [range(int(p[0]), int(p[-1]) + 1) for p in parts if len(p)]
        self.worker_n = np.array([min(n, r.stop * SAMPLE_BLOCK) - r.start * SAMPLE_BLOCK for r in self.worker_blocks])
        self.shift = model.feature_moments()[0]
        tables = sampler_tables(budget, model.feature_ops())
        self.fused = tables is not None
        if self.fused:  # compiled sampling: every worker's lanes start at its first block
            self.tables = tables
            self.worker_lanes = [pcg_lanes(seed, r.start * SAMPLE_BLOCK, len(budget.factor_laws))
                                 for r in self.worker_blocks]
        else:  # numpy sampling, block by block
            self.tables = (np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0), np.zeros(0), np.zeros((0, 3), np.int64),
                           np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 0)))
            self.worker_lanes = [(np.zeros((2, LANES), np.uint64), np.zeros(6, np.uint64))] * len(self.worker_blocks)

    def features(self, k: int) -> np.ndarray:
        """Features (b, F) float64 of block k, sampled through numpy."""
        return self.model.features(self.budget.sample_block(self.seed, k, self.n))

    def pilot(self, m: int) -> np.ndarray:
        """Features (Fp, m) float32 of the first m samples, zero from row F on (Fp = :func:`padded_features`)."""
        nF = self.shift.size
        out = np.zeros((padded_features(nF), m), np.float32)
        if not self.fused:
            blocks = [self.features(k) for k in range(-(-m // SAMPLE_BLOCK))]
            out[:nF] = np.concatenate(blocks)[:m].T
            return out
        D = len(self.budget.factor_laws)
        lanes, consts = pcg_lanes(self.seed, 0, D)
        U, X, F = np.empty((D, TILE)), np.empty((D, TILE)), np.empty((nF, TILE))
        for t0 in range(0, m, TILE):
            k = min(TILE, m - t0)
            draw_features(lanes, consts, *self.tables, k, U, X, F)
            out[:nF, t0:t0 + k] = F[:, :k]
        return out

    def moments(self, S1: np.ndarray, S2: np.ndarray) -> Moments:
        """Moments from per-segment sums S1 (S, F) and S2 (S, F, F) about :attr:`shift`."""
        nb = np.diff(self.batch_edges).astype(float)
        B1 = np.zeros((len(nb), S1.shape[1]))
        B2 = np.zeros((len(nb),) + S2.shape[1:])
        np.add.at(B1, self.seg_batch, S1)
        np.add.at(B2, self.seg_batch, S2)

        def mean_cov(s1, s2, k):
            k = np.asarray(k, dtype=float)[..., None]
            with np.errstate(divide="ignore", invalid="ignore"):
                return self.shift + s1 / k, (s2 - np.einsum("...f,...g->...fg", s1, s1 / k)) / (k[..., None] - 1)

        mean, cov = mean_cov(B1.sum(0), B2.sum(0), self.n)
        bm, bc = mean_cov(B1, B2, nb)
        return Moments(mean, cov, bm, bc)

    # ------------------------------------------------------------------ passes
    def scan(self, C32: np.ndarray, win: "_Windows", main: bool, tols: tuple, sums: dict | None,
             pool: ThreadPoolExecutor) -> list[dict]:
        """One pass over all blocks for the poses of ``C32`` (P, 3, Fp), zero from column F on (Fp =
        :func:`padded_features`); per-worker accumulators.

        On the main pass ``sums`` receives the norm sums per pose and segment
        (``possum``) and, if it holds ``S1`` and ``S2``, the feature sums per segment. ``tols``: the
        norm's (mm) and ``|dphi|``'s (rad) exceedance thresholds, None for one not counted.
        """
        P, nF = C32.shape[0], self.shift.size
        tol32 = np.array([-1.0 if t is None else t for t in tols], np.float32)
        with_sums = sums is not None and "S1" in sums
        S1 = sums["S1"] if with_sums else np.zeros((0, nF))
        S2 = sums["S2"] if with_sums else np.zeros((0, nF, nF))
        possum = sums["possum"] if sums is not None else np.zeros((P, self.seg_start.size))
        key = feature_key(nF)

        def work(w: int) -> dict:
            acc = {"below": np.zeros(win.shape, np.int64), "inside": np.zeros(win.shape, np.int64),
                   "sub": np.zeros(win.shape + (SUB_BINS,), np.int64), "buf": np.empty(win.size[w], np.float32),
                   "vmax": np.zeros((P, 2), np.float32), "exceed": np.zeros((P, 3), np.int64)}
            lanes, consts = self.worker_lanes[w]
            lanes = lanes.copy()                  # each call leaves them at its last block's end
            blocks = self.worker_blocks[w]
            ranges = ((k, min(blocks.stop, k + STOP_BLOCKS), np.zeros((0, nF)))
                      for k in range(blocks.start, blocks.stop, STOP_BLOCKS)) if self.fused else \
                ((k, k + 1, self.features(k)) for k in blocks)
            for k0, k1, Fext in ranges:
                check_stop()
                scan_blocks(k0, k1, self.n, lanes, consts, *self.tables, Fext, C32, key, self.shift,
                            self.block_segs, self.seg_start, self.seg_stop, with_sums, S1, S2, tol32, main,
                            win.lo, win.hi, win.nwin, win.edges, win.off[w], win.cap[w], acc["below"],
                            acc["inside"], acc["sub"], acc["buf"], acc["vmax"], possum, acc["exceed"])
            return acc

        return list(pool.map(work, range(len(self.worker_blocks))))


class _Windows:
    """Selection windows of a chunk of poses, as the arrays :func:`scan_block` reads.

    ``specs[p][o]`` lists the disjoint windows of pose p and output o as
    ``(lo, hi, top, caps, ranks)``: float32 bounds, the top of the sub-bin
    edges (``hi`` unless that is infinite), the capacity per worker and the
    indices of the ranks the window is meant to hold.
    """

    def __init__(self, specs: list, n_workers: int, limit: np.ndarray):
        P = len(specs)
        W = max(1, max(len(specs[p][o]) for p in range(P) for o in range(2)))
        self.specs = specs
        self.shape = (P, 2, W)
        self.lo = np.full(self.shape, _F32_INF, np.float32)
        self.hi = np.full(self.shape, _F32_INF, np.float32)
        self.nwin = np.zeros((P, 2), np.int64)
        self.edges = np.full(self.shape + (SUB_BINS + 1,), _F32_INF, np.float32)
        caps = np.zeros((n_workers,) + self.shape, np.int64)
        j = np.arange(SUB_BINS + 1) / SUB_BINS
        for p in range(P):
            for o in range(2):
                self.nwin[p, o] = len(specs[p][o])
                for w, (lo, hi, top, cap, _) in enumerate(specs[p][o]):
                    self.lo[p, o, w], self.hi[p, o, w] = lo, hi
                    e = (float(lo) + (float(top) - float(lo)) * j).astype(np.float32)
                    e = np.maximum.accumulate(np.clip(e, lo, hi))
                    e[0], e[-1] = lo, hi
                    self.edges[p, o, w] = e
                    caps[:, p, o, w] = np.minimum(cap, limit)
        self.cap = caps
        flat = caps.reshape(n_workers, -1)
        self.off = (np.cumsum(flat, axis=1) - flat).reshape(caps.shape)
        self.size = flat.sum(axis=1)


def _merge(windows: list) -> list:
    """Windows ``(lo, hi, top, caps, ranks)`` merged where they overlap: disjoint, by increasing lo."""
    out: list = []
    for lo, hi, top, caps, ranks in sorted(windows, key=lambda w: float(w[0])):
        if out and lo < out[-1][1]:
            L, H, T, C, R = out[-1]
            out[-1] = (L, max(H, hi), max(T, top), C + caps, R + ranks)
        else:
            out.append((lo, hi, top, np.asarray(caps), list(ranks)))
    return out


def pilot_fraction(ranks: np.ndarray, n: int, m: int) -> float:
    """Expected fraction of the n values kept per output by pilot windows of m samples (at most 1)."""
    f = np.unique(np.round(ranks / max(n - 1, 1), 2))  # ranks close together share a window
    return float(min(1.0, np.sum(2 * (_PILOT_SE * np.sqrt(f * (1 - f) / m) + 3.0 / m))))


def pilot_windows(vals: np.ndarray, ranks: np.ndarray, n: int, worker_n: np.ndarray) -> list:
    """Disjoint windows around each rank (0-based in n) from the pilot's values ``vals`` (unsorted).

    The window of a rank at quantile f spans the pilot's order statistics at
    f +- 5 pilot standard errors; its capacity per worker is the expected
    count with a margin.
    """
    m = vals.size
    f = ranks / max(n - 1, 1)
    half = _PILOT_SE * np.sqrt(f * (1 - f) * m) + 2.0
    i_lo = np.maximum(np.floor(f * (m - 1) - half).astype(np.int64), 0)
    i_hi = np.minimum(np.ceil(f * (m - 1) + half).astype(np.int64), m)
    idx = np.unique(np.concatenate([i_lo, i_hi[i_hi < m], [m - 1]]))
    stat = order_statistics(vals, idx)  # the pilot's order statistics at idx
    lo = np.where(i_lo > 0, stat[np.searchsorted(idx, i_lo)], np.float32(0.0))
    top_all = stat[-1] * np.float32(2.0) + np.float32(1e-30)
    inner = np.nextafter(stat[np.minimum(np.searchsorted(idx, i_hi), idx.size - 1)], _F32_INF)
    hi = np.where(i_hi < m, inner, _F32_INF)
    top = np.where(i_hi < m, inner, top_all)
    none = np.zeros_like(worker_n)
    merged = _merge([(lo[r], hi[r], top[r], none, [r]) for r in range(len(ranks))])
    k = count_below(vals, np.array([b for w in merged for b in w[:2]], np.float32)).reshape(-1, 2)
    out = []
    for (lo, hi, top, _, rs), (k_lo, k_hi) in zip(merged, k):  # capacity from the merged window's pilot count
        expected = (k_hi - k_lo + 1) / m * worker_n
        out.append((lo, hi, top, np.ceil(1.2 * expected + 6 * np.sqrt(expected) + 64).astype(np.int64), rs))
    return out


def select_order_statistics(stream: Stream, C32: np.ndarray, ranks: np.ndarray, pilot_FT: np.ndarray,
                            tols: tuple, sums: dict, pool: ThreadPoolExecutor,
                            max_window_values: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact order statistics at ``ranks`` of the norm and |dphi| of each pose of a chunk.

    Returns
    -------
    values : (P, 2, R) float32
        Order statistics (0 norm mm, 1 |dphi| rad) at the ranks.
    vmax : (P, 2) float32
        Largest values.
    exceed : (P, 3) int64
        Counts of norms above ``tols[0]`` (mm), of ``|dphi|`` above ``tols[1]`` (rad), and of either (a
        tolerance None: that output is not counted).
    Fills ``sums`` (per-segment norm sums, and feature sums if asked for) on the first pass.
    """
    n, P, R = stream.n, C32.shape[0], len(ranks)
    limit = np.ceil(max_window_values * stream.worker_n / n).astype(np.int64)
    m = pilot_FT.shape[1]
    key = feature_key(C32.shape[2])

    def pilot(p):
        pos, phi = np.empty(m, np.float32), np.empty(m, np.float32)
        pose_values(pilot_FT, C32[p], pos, phi, key)
        return [pilot_windows(v, ranks, n, stream.worker_n) for v in (pos, phi)]

    specs = list(pool.map(pilot, range(P)))
    values = np.full((P, 2, R), np.nan, np.float32)
    vmax = exceed = None
    while True:
        win = _Windows(specs, len(stream.worker_blocks), limit)
        main = vmax is None
        accs = stream.scan(C32, win, main, tols, sums if main else None, pool)
        if main:
            vmax = np.max([a["vmax"] for a in accs], axis=0)
            exceed = np.sum([a["exceed"] for a in accs], axis=0)
        specs = _resolve(win, accs, ranks, vmax, values, stream.worker_n)
        if not any(specs[p][o] for p in range(P) for o in range(2)):
            return values, vmax, exceed


def _resolve(win: _Windows, accs: list, ranks: np.ndarray, vmax: np.ndarray, values: np.ndarray,
             worker_n: np.ndarray) -> list:
    """Read off the ranks each window holds into ``values``; windows for the next pass for the others."""
    below = np.array([a["below"] for a in accs])  # (workers, P, 2, W)
    inside = np.array([a["inside"] for a in accs])
    P = win.shape[0]
    specs = [[[], []] for _ in range(P)]
    for p in range(P):
        for o in range(2):
            new = []
            for w, (lo, hi, _, _, rs) in enumerate(win.specs[p][o]):
                bw, iw, cw = below[:, p, o, w], inside[:, p, o, w], win.cap[:, p, o, w]
                B, I = int(bw.sum()), int(iw.sum())
                parts = [a["buf"][win.off[k, p, o, w]:win.off[k, p, o, w] + min(iw[k], cw[k])]
                         for k, a in enumerate(accs)]
                sub = None
                held = [r for r in rs if B <= ranks[r] < B + I]
                if held and np.all(iw <= cw):  # every value of the window was kept: select
                    kth = ranks[held] - B
                    order = np.argsort(kth)
                    values[p, o, np.asarray(held)[order]] = order_statistics(np.concatenate(parts), kth[order])
                    held = []
                for r in rs:
                    rank = int(ranks[r])
                    if rank < B:  # below the window: the pilot was off
                        new.append((np.float32(0.0), lo, lo, bw, [r]))
                    elif rank >= B + I:  # above it
                        top = np.nextafter(vmax[p, o], _F32_INF)
                        new.append((hi, top, top, worker_n - bw - iw, [r]))
                    elif r not in held:
                        pass  # selected above
                    elif np.nextafter(lo, _F32_INF) >= hi:  # a window of one float32 value
                        values[p, o, r] = lo
                    else:  # too many values: narrow to the sub-bin holding the rank
                        e = win.edges[p, o, w]
                        if sub is None:
                            sub = np.array([a["sub"][p, o, w] + np.bincount(np.searchsorted(e, part, side="right") - 1,
                                                                           minlength=SUB_BINS)
                                            for a, part in zip(accs, parts)])
                        j = int(np.searchsorted(np.cumsum(sub.sum(0)), rank - B, side="right"))
                        new.append((e[j], e[j + 1], e[j + 1], sub[:, j], [r]))
            specs[p][o] = _merge(new)
    return specs
