"""Exact search for the least-cost tolerance classes: a batched envelope and branch and bound.

Every input's class sets its term's interval (mm or deg; a clearance term
rho cos(zeta - omega) with zeta on the full turn spans [-rho_max, rho_max]).
The exact worst case of the linear model (:mod:`~prp3mc.worstcase`) is the largest
norm over the 8 corners of the box the three legs' u_i fill, and that box
only grows when an interval grows: the envelope over the region is monotone
under interval inclusion. :class:`Problem` evaluates it for a batch of K
candidate choices at all N poses at once (two matrix products for the
boxes, then the worst case's own corner maxima,
:func:`~prp3mc.worstcase._kernel.zonotope_maxima`, over the K x N boxes).

:class:`Search` finds the proven least-cost choice by best-first branch and
bound over the inputs, one class at a time. A node fixes the classes of the
first d inputs; for the rest it evaluates

- the *bound completion*: every open input at the intersection of its
  classes' intervals, contained in whichever class it takes, so its envelope
  is a lower bound of every completion's: above the spec, the node is pruned;
- the *cheap completion*: every open input at its cheapest class, a real
  choice of cost equal to the node's cost lower bound: within the spec, it
  is optimal for the node, and optimal overall once the node is the cheapest
  in the queue.

Inputs whose classes share no common interval are branched first and get no
bound until they are fixed, so the search stays exact for any menu.

A budget's systematic effects (its ``[effects]`` table) are not allocated:
they stay fixed in every candidate, as a fixed centre (known shifts and the
mean of the effects' factors), fixed widths of the legs' u_i (backlash) and
a fixed shared generator (thermal, one temperature for all legs, so the
maxima are over 16 corners); the envelope stays monotone in the classes'
intervals, so the bounds stay exact.

The statistical screen (for a percentile spec) uses the closed-form mean and
covariance of the position error: a normal-approximation bound
``|mu| + sqrt(lambda_max(Sigma) chi2_2(q))`` on its q-quantile (under
normality the ellipse of probability q lies in that disc), capped by the
exact worst case (a quantile never exceeds the maximum). For open inputs it
uses the smallest variance and a triangle-inequality bound on ``|mu|``, again a
lower bound of every completion's screen.
"""

from __future__ import annotations

import heapq
import itertools
import math

import numpy as np

from ..errors import ResourceError
from ..limits import MEMORY_MARGIN, available_memory, format_bytes
from ..units import RAD2DEG
from ..kinematics.geometry import Geometry
from .classes import ClassMenu
from ..model.budget import Budget
from ..model.linear import linear_model
from ..worstcase._kernel import zonotope_maxima, zonotope_scratch
from ..worstcase.envelope import term_bounds

__all__ = ["Problem", "Search", "least_cost", "QUANTITIES"]

#: Constrained quantities: worst-case position (mm), worst-case ``|dphi|`` (deg), screened position quantile (mm).
QUANTITIES = ("position", "phi", "screen")
_CHUNK_ELEMENTS = 1 << 18   # K x N elements per evaluated block


def _node_bytes(n_inputs: int) -> int:
    """Bytes one queued node holds, at most: its heap entry (a 5-tuple and its list slot, a key of up to two
    floats, a counter) and its class indices (a tuple of small ints, which Python shares); measured by
    ``tests/test_allocation_memory.py``."""
    return (96 + 8) + (56 + 2 * 24) + 32 + (56 + 8 * n_inputs)


def _over_limits(search: "Search", queued: int) -> None:
    """Refuse (ResourceError) a search whose queue outgrows the memory it found free when it started.

    The number of choices of a menu (6^27 for nine families of six classes
    on three legs) says nothing of what branch and bound examines, which
    cannot be told before it runs; time is bounded by ``prp3mc --max-hours``
    (a wall-clock stop), memory here.
    """
    if queued <= search.max_queued:
        return
    memory = queued * _node_bytes(len(search.pb.inputs))
    choices = math.prod(int(n) for n in search.pb.n_classes)
    raise ResourceError(f"tolerance allocation over {len(search.pb.inputs)} inputs ({choices:.3g} choices of "
                        f"classes) needs more than this machine's memory ({format_bytes(memory)} queued): the "
                        f"search examined {search.nodes} candidates without proving the least cost; give fewer "
                        "classes or families, or a looser spec")


class Problem:
    """The classes of every input as term intervals and moments, and the model at the poses.

    Parameters
    ----------
    geometry : Geometry
    menu : ClassMenu
    poses : ndarray, shape (N, 3)
        ``[x_mm, y_mm, phi_deg]``.
    k_sigma : float, optional
        Bound unbounded laws as mean ± k_sigma·sd.
    percentile : float, optional
        q (in %) of the statistical screen.
    fixed : Budget, optional
        A budget whose ``[effects]`` stay fixed in every candidate and whose
        ``[correlation]`` every candidate takes (its inputs' laws play no
        part: the classes choose them).

    Attributes
    ----------
    inputs : tuple of str
        J inputs in :attr:`ClassMenu.inputs` order.
    mid, half, mean, var, cost : ndarray, shape (J, M)
        Per input and class (padded to the longest menu M with the last
        class): term interval midpoint and half-width, term mean and
        variance (mm or deg and their squares), cost.
    n_classes : ndarray (J,)
    fixed : dict of str to ndarray
        The effects' fixed parts at the poses: ``u_mid`` (N, 3) centre and
        ``u_half`` (N, 3) half-widths of the legs' u_i, ``ext`` (N, G, 3)
        shared generators of u (terms of all legs), and, for the screen,
        ``mean`` (N, 3) and ``cov`` (N, 3, 3) of the pose error (mm, mm, rad).
        All zero without effects (G = 0).
    """

    def __init__(self, geometry: Geometry, menu: ClassMenu, poses: np.ndarray, *,
                 k_sigma: float | None = None, percentile: float | None = None, fixed: Budget | None = None):
        self.menu, self.poses = menu, np.asarray(poses, dtype=float).reshape(-1, 3)
        self.inputs = menu.inputs
        self.fixed_budget = fixed if fixed is not None and (fixed.effects or fixed.correlated) else None
        first = {name: menu.classes_of(name)[0].name for name in self.inputs}
        model = linear_model(geometry, self.budget(first), self.poses)
        N, J = self.poses.shape[0], len(self.inputs)
        assert model.terms[:J] == self.inputs
        legs = np.array(model.legs[:J])
        columns = model.columns
        self.P = np.ascontiguousarray(np.moveaxis(columns[..., :J], -1, 0))  # (J, N, 3): mm, mm, rad per term unit
        self._Ai = np.ascontiguousarray(np.moveaxis(model.Ainv, 0, -1))      # (3, 3, N): A^-1, poses last
        self._Wu = model.scale[:, :J].T[:, :, None] * (legs[:, None] == np.arange(3))[:, None, :]  # (J, N, 3)
        self.fixed = _fixed_parts(model, J, k_sigma)
        from scipy.stats import chi2  # imported when used: parsing a study imports this module
        self.kq = None if percentile is None else float(np.sqrt(chi2.ppf(percentile / 100.0, 2)))
        self.n_classes = np.array([len(menu.classes_of(n)) for n in self.inputs])
        M = int(self.n_classes.max())
        table = np.empty((5, J, M))
        for j, name in enumerate(self.inputs):
            classes = menu.classes_of(name)
            for m in range(M):
                law = classes[min(m, len(classes) - 1)]
                table[:, j, m] = _term(name, law.law, k_sigma) + (law.cost,)
        self.mid, self.half, self.mean, self.var, self.cost = table

    def class_name(self, j: int, m: int) -> str:
        return self.menu.classes_of(self.inputs[j])[m].name

    def budget(self, choice: dict) -> Budget:
        """The error budget of a choice ``{input: class name}``, with the fixed effects."""
        return self.menu.budget(choice, self.fixed_budget)

    def evaluate(self, mid, half, mean=None, dmean=None, var=None, at=None) -> dict:
        """Per-pose envelopes of K candidates, each (K, n).

        Parameters
        ----------
        mid, half : ndarray, shape (K, J)
            Every input's term interval (midpoint, half-width), mm or deg.
        mean, dmean, var : ndarray, shape (K, J), optional
            Term mean (± dmean when only its range is known) and variance,
            for the statistical screen.
        at : ndarray of int, optional
            Evaluate at these n pose indices only (default: all N poses).

        Returns
        -------
        dict
            ``position`` (mm) and ``phi`` (deg): exact worst cases;
            ``screen`` (mm): the screened quantile, if the moments are given.
        """
        at = slice(None) if at is None else np.asarray(at)
        P, Wu, Ai = self.P[:, at], self._Wu[:, at], np.ascontiguousarray(self._Ai[..., at])
        fixed = {k: v[at] for k, v in self.fixed.items()}
        step = max(1, _CHUNK_ELEMENTS // P.shape[1])
        parts = [_envelope(P, Wu, Ai, self.kq, fixed,
                           *(None if a is None else a[s:s + step] for a in (mid, half, mean, dmean, var)))
                 for s in range(0, mid.shape[0], step)]
        return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}

    def envelopes(self, idx) -> dict:
        """Per-pose envelopes (K, N) of complete choices ``idx`` (K, J) of class indices."""
        idx = np.atleast_2d(idx)
        j = np.arange(len(self.inputs))
        stat = self.kq is not None
        return self.evaluate(self.mid[j, idx], self.half[j, idx], self.mean[j, idx] if stat else None,
                             np.zeros(idx.shape) if stat else None, self.var[j, idx] if stat else None)


def _fixed_parts(model, J: int, k_sigma) -> dict:
    """The fixed parts (see :attr:`Problem.fixed`) of the model's terms from J on (the effects)."""
    N = model.poses.shape[0]
    out = {"u_mid": np.zeros((N, 3)), "mean": np.zeros((N, 3)), "cov": np.zeros((N, 3, 3)),
           "u_half": np.zeros((N, 3)), "ext": np.zeros((N, 0, 3))}
    if len(model.terms) == J:
        return out
    tb = term_bounds(model, model.budget.bounds(k_sigma))[:, J:]                # (N, E, 2)
    weights, scale = model.weights[..., J:], model.scale[:, J:]                   # (N, 3, E), (N, E)
    mid, half = tb.mean(-1), 0.5 * (tb[..., 1] - tb[..., 0])
    onehot = (np.array(model.legs[J:])[:, None] == np.arange(3)).astype(float)   # (E, 3); none for all-leg terms
    shared = [t - J for t in model.shared]
    out["u_mid"] = (scale * mid) @ onehot + np.einsum("nie,ne->ni", weights[..., shared], mid[:, shared])
    out["u_half"] = (np.abs(scale) * half) @ onehot
    out["ext"] = np.moveaxis(weights[..., shared] * half[:, None, shared], -1, -2)  # (N, G, 3)
    fmean, fcov = model.feature_moments()
    coef = model.coef
    F = coef.shape[-1]
    own = np.zeros(F, dtype=bool)           # the features of the effects: those after the inputs' features
    own[_n_input_features(model, J):] = True
    out["mean"] = np.einsum("nof,f->no", coef[..., own], fmean[own])
    out["cov"] = np.einsum("nof,fg,nqg->noq", coef[..., own], fcov[np.ix_(own, own)], coef[..., own])
    return out


def _n_input_features(model, J: int) -> int:
    """Features of the first J terms (a clearance has two)."""
    return sum(2 if tl.kind == "clearance" else 1 for tl in model.term_laws[:J])


def _envelope(P, Wu, Ai, kq, fixed, mid, half, mean, dmean, var) -> dict:
    """The envelopes of :meth:`Problem.evaluate` for one block of K candidates, at n poses.

    The worst cases are :func:`~prp3mc.worstcase._kernel.zonotope_maxima` (the one definition of the
    corner maxima) over the K x n boxes of u, each candidate's poses in turn.
    """
    J, n = P.shape[:2]
    K = mid.shape[0]
    u_mid = (mid @ Wu.reshape(J, n * 3)).reshape(K, n, 3) + fixed["u_mid"]
    u_half = (half @ np.abs(Wu).reshape(J, n * 3)).reshape(K, n, 3) + fixed["u_half"]
    G, m = fixed["ext"].shape[1], K * n
    ext = np.tile(np.moveaxis(fixed["ext"], 0, -1), K)                        # (G, 3, K n)
    values, codes = np.empty((4, m)), np.empty((4, m), dtype=np.int16)
    zonotope_maxima(np.tile(Ai, K), np.ascontiguousarray(u_mid.reshape(m, 3).T),
                    np.ascontiguousarray(u_half.reshape(m, 3).T), ext, values, codes, 0, m,
                    zonotope_scratch(3 + G, m))
    out = {"position": values[0].reshape(K, n), "phi": values[1].reshape(K, n) * RAD2DEG}
    if mean is not None:
        px, py = P[..., 0], P[..., 1]
        mu = (mean @ P.reshape(J, n * 3)).reshape(K, n, 3) + fixed["mean"]
        mu_lb = np.maximum(0.0, np.hypot(mu[..., 0], mu[..., 1]) - dmean @ np.hypot(px, py))
        cov = fixed["cov"]
        a, b, c = var @ (px * px) + cov[:, 0, 0], var @ (px * py) + cov[:, 0, 1], var @ (py * py) + cov[:, 1, 1]
        lam = 0.5 * (a + c) + np.sqrt(np.maximum(0.0, 0.25 * (a - c) ** 2 + b * b))
        out["screen"] = np.minimum(out["position"], mu_lb + kq * np.sqrt(np.maximum(lam, 0.0)))
    return out


def _term(name: str, law, k_sigma) -> tuple[float, float, float, float]:
    """Term interval midpoint and half-width, mean and variance of an input's law."""
    lo, hi = law.bounds(k_sigma)
    if name.startswith("rho_"):   # rho cos(zeta - omega), zeta uniform on the full turn
        return 0.0, hi, 0.0, 0.5 * (law.var + law.mean ** 2)
    return 0.5 * (lo + hi), 0.5 * (hi - lo), law.mean, law.var


class Search:
    """Best-first branch and bound over the classes of :class:`Problem` under ``limits``.

    Candidates are first evaluated at an *active set* of poses (those that
    were the maximiser of a candidate checked at every pose): the maximum
    over a subset is a lower bound of the region maximum, so pruning on it
    stays exact; a choice is only accepted after a check at every pose,
    whose maximiser joins the active set when it fails.

    Parameters
    ----------
    problem : Problem
    limits : dict of str to float
        Upper limit of the region maximum of each constrained quantity
        (:data:`QUANTITIES`; mm or deg), > 0; None entries are ignored.
    batch : int
        Nodes expanded per vectorised evaluation.

    Attributes
    ----------
    nodes : int
        Candidates evaluated (bound and cheap completions and full checks).
    max_queued : int
        Nodes the queue may hold: :data:`~prp3mc.limits.MEMORY_MARGIN` of the
        memory available when the search was set up.
    """

    def __init__(self, problem: Problem, limits: dict, batch: int = 16):
        self.pb, self.batch, self.nodes = problem, batch, 0
        self.limits = {q: float(v) for q, v in limits.items() if v is not None}
        pb, J = problem, len(problem.inputs)
        lo, hi = pb.mid - pb.half, pb.mid + pb.half
        cap_lo, cap_hi = lo.max(axis=1), hi.min(axis=1)
        is_open = cap_lo <= cap_hi                  # inputs whose classes share an interval: bounded when open
        self._cheap = np.lexsort((pb.half, pb.cost), axis=1)[:, 0]          # cheapest, then narrowest
        self._min_cost = pb.cost[np.arange(J), self._cheap]
        # inputs without a common interval first, then by their influence on the constrained quantities
        scale = np.array([self.limits.get("position", self.limits.get("screen", 1.0))] * 2
                         + [self.limits.get("phi", 1.0) / RAD2DEG])
        spread = 2 * (pb.half.max(axis=1) - pb.half.min(axis=1)) + np.ptp(pb.mid, axis=1)
        influence = np.sqrt(((pb.P / scale) ** 2).sum(-1)).max(-1) * spread
        self.order = np.lexsort((-influence, is_open))
        self._n_closed = int((~is_open).sum())
        bound = {"mid": np.where(is_open, 0.5 * (cap_lo + cap_hi), 0.0),
                 "half": np.where(is_open, 0.5 * np.maximum(cap_hi - cap_lo, 0.0), 0.0),
                 "mean": 0.5 * (pb.mean.max(1) + pb.mean.min(1)), "dmean": 0.5 * np.ptp(pb.mean, axis=1),
                 "var": pb.var.min(1)}
        per_class = {"mid": pb.mid, "half": pb.half, "mean": pb.mean, "dmean": np.zeros_like(pb.mean), "var": pb.var}
        # column M of each table: the value of an open input in the bound completion
        self._tables = {k: np.concatenate([per_class[k], bound[k][:, None]], axis=1) for k in bound}
        self._keys = ("mid", "half", "mean", "dmean", "var") if "screen" in self.limits else ("mid", "half")
        self.active = np.zeros(0, dtype=int)
        self.max_queued = int(MEMORY_MARGIN * available_memory()) // _node_bytes(J)

    # ------------------------------------------------------------ evaluation
    def ratio(self, env: dict) -> np.ndarray:
        """Largest value/limit over the constraints and evaluated poses, (K,); 0 without limits."""
        r = np.zeros(next(iter(env.values())).shape[0])
        for q, lim in self.limits.items():
            r = np.maximum(r, env[q].max(axis=-1) / lim)
        return r

    def _rows(self, idx: np.ndarray) -> dict:
        J = idx.shape[1]
        return {k: self._tables[k][np.arange(J), idx] for k in self._keys}

    def _full(self, idx: np.ndarray) -> float:
        """Ratio of one choice (J,) at every pose; its maximiser joins the active set."""
        self.nodes += 1
        env = self.pb.evaluate(**self._rows(idx[None]))
        per_pose = np.zeros(self.pb.poses.shape[0])
        for q, lim in self.limits.items():
            per_pose = np.maximum(per_pose, env[q][0] / lim)
        self.active = np.union1d(self.active, [int(np.argmax(per_pose))])
        return float(per_pose.max())

    def _ratios(self, A: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Active-set ratios of the bound and the cheap completions of nodes A (K, J); -1 = open."""
        M, K = self._tables["mid"].shape[1] - 1, A.shape[0]
        idx = np.concatenate([np.where(A >= 0, A, M), np.where(A >= 0, A, self._cheap)])
        self.nodes += 2 * K
        r = self.ratio(self.pb.evaluate(**self._rows(idx), at=self.active))
        return np.where(depth >= self._n_closed, r[:K], 0.0), r[K:]

    def cost_lb(self, A: np.ndarray) -> np.ndarray:
        """Cost of each node's cheap completion: a lower bound of every completion's cost, (K,)."""
        J = A.shape[1]
        return np.where(A >= 0, self.pb.cost[np.arange(J), np.maximum(A, 0)], self._min_cost).sum(axis=1)

    def complete(self, A) -> np.ndarray:
        """The cheap completion of node ``A`` (J,): open inputs at their cheapest class."""
        return np.where(np.asarray(A) >= 0, A, self._cheap)

    def _children(self, popped) -> tuple[np.ndarray, np.ndarray]:
        children, depths = [], []
        for node in popped:
            A, d = node[2], node[3]
            j = self.order[d]
            for m in range(self.pb.n_classes[j]):
                child = list(A)
                child[j] = m
                children.append(child)
                depths.append(d + 1)
        return np.array(children), np.array(depths)

    def _start(self):
        J = len(self.pb.inputs)
        root = np.full((1, J), -1)
        if not self.limits:
            return root, None
        self._full(self.complete(root[0]))
        if self._n_closed == 0:
            self._full(np.where(root[0] >= 0, root[0], self._tables["mid"].shape[1] - 1))
        return root, np.zeros(1, dtype=int)

    # ------------------------------------------------------------ search
    def least_cost(self) -> np.ndarray | None:
        """Class indices (J,) of the proven least-cost choice within the limits, or None if none is."""
        root, depth = self._start()
        if depth is None:
            return self.complete(root[0])
        J = root.shape[1]
        counter, heap = itertools.count(), []

        def push(A, depth):
            _over_limits(self, len(heap))
            r_bound, r_cheap = self._ratios(A, depth)
            costs, nodes, depths = self.cost_lb(A).tolist(), A.tolist(), depth.tolist()    # Python numbers: small
            for k in np.flatnonzero(r_bound <= 1.0):
                done = r_cheap[k] <= 1.0 and self._full(self.complete(A[k])) <= 1.0
                if depths[k] == J and not done:      # a complete choice that fails at some pose
                    continue
                heapq.heappush(heap, (costs[k], next(counter), tuple(nodes[k]), depths[k], done))

        push(root, depth)
        while heap:
            if heap[0][4]:
                return self.complete(heap[0][2])
            popped = []
            while heap and not heap[0][4] and len(popped) < self.batch:
                popped.append(heapq.heappop(heap))
            push(*self._children(popped))
        return None

    def closest(self) -> np.ndarray:
        """Class indices (J,) of the choice with the smallest ratio to the limits (then the cheapest)."""
        root, depth = self._start()
        J = root.shape[1]
        counter, heap = itertools.count(), []

        def push(A, depth):
            _over_limits(self, len(heap))
            r_bound, _ = self._ratios(A, depth)
            keys, nodes, depths = zip(r_bound.tolist(), self.cost_lb(A).tolist()), A.tolist(), depth.tolist()
            for key, node, d in zip(keys, nodes, depths):
                heapq.heappush(heap, (key, next(counter), tuple(node), d, False))

        push(root, depth)
        while True:
            key, _, A, d, exact = heap[0]
            if exact:
                return np.array(A)
            if d == J:      # a complete choice: its key becomes its ratio at every pose
                heapq.heapreplace(heap, ((self._full(np.array(A)), key[1]), next(counter), A, d, True))
                continue
            popped = []
            while heap and heap[0][3] < J and len(popped) < self.batch:
                popped.append(heapq.heappop(heap))
            push(*self._children(popped))


def least_cost(problem: Problem, limits: dict) -> tuple[np.ndarray | None, int]:
    """The least-cost choice within ``limits`` and, among equally cheap ones, the farthest within them.

    Returns the class indices (J,) or None when no choice meets the limits,
    and the number of candidates evaluated.
    """
    search = Search(problem, limits)
    idx = search.least_cost()
    nodes = search.nodes
    if idx is None or not search.limits:
        return idx, nodes
    cost = float(problem.cost[np.arange(len(idx)), idx].sum())
    while True:   # ask for strictly less, at every limit at once, until the cost rises
        r = search.ratio(problem.envelopes(idx))[0]
        tighter = Search(problem, {q: v * r * (1 - 1e-9) for q, v in search.limits.items()})
        better = tighter.least_cost()
        nodes += tighter.nodes
        if better is None or problem.cost[np.arange(len(idx)), better].sum() > cost * (1 + 1e-12) + 1e-300:
            return idx, nodes
        idx = better
