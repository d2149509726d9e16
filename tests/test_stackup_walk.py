"""The lattice walk's shortcuts (prp3mc/stackup/truncation.py) give the bits of what they replace."""

from __future__ import annotations

import math

import numpy as np

from prp3mc.stackup.characteristic import envelope
from prp3mc.stackup.truncation import _BINS, _CHUNK, _bin, _inverse_envelope, _only_inverse, select_points


def test_the_drop_bin_from_the_exponent_bits_is_frexps():
    """The bin of F from its exponent field is ``floor(log2 F) + 1300`` (clamped), as ``math.frexp`` gives it:
    normal values over the whole range, powers of two and their neighbours, subnormals, the largest double."""
    rng = np.random.default_rng(3)
    values = list(10.0 ** rng.uniform(-307.0, 307.0, 20_000))
    for k in range(-1074, 1024):
        p = math.ldexp(1.0, k)
        values += [p, math.nextafter(p, 0.0), math.nextafter(p, math.inf)]
    values += [5e-324, 1e-310, 2.2250738585072014e-308, 1.7976931348623157e308]
    for f in values:
        if 0.0 < f < math.inf:
            assert _bin(f) == min(_BINS - 1, max(0, math.frexp(f)[1] - 1 + 1300)), f


def test_the_inverse_envelope_is_the_envelope_to_the_bit():
    """A row with a1 / x alone: the walk's shortcut gives envelope()'s bits at every argument (0, tiny, flat part,
    the kink, far out); a row with any other form or a normal factor is not taken for one."""
    rng = np.random.default_rng(5)
    for a1 in np.concatenate([10.0 ** rng.uniform(-3.0, 3.0, 200), [91.8938125, 25.0, 80.0]]):
        row = np.array([a1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        assert _only_inverse(row)
        for x in np.concatenate([[0.0, 5e-324, a1, math.nextafter(a1, 0.0), math.nextafter(a1, math.inf)],
                                 a1 * 10.0 ** rng.uniform(-6.0, 6.0, 200)]):
            assert _inverse_envelope(a1, x) == envelope(*row, x)
    for j in (1, 2, 4, 5, 6, 7):                        # a2, a15, bh, f2, w, sd
        row = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        row[j] = 0.5
        assert not _only_inverse(row)
    assert not _only_inverse(np.zeros(8))               # no form: the envelope is 1, not min(1, 0 / x)
    assert _only_inverse(np.array([1.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0]))   # w0 counts only with bh


def test_the_walk_keeps_each_point_once_across_its_chunks():
    """The walk appends its points in chunks of _CHUNK, the arrays growing between chunks (from 4096 entries):
    at poses of both budgets walking 3 to 20 times that (S = 0.4 mm), the kept points are distinct lattice
    points of the half-lattice (n_2 > 0, or n_2 = 0 and n_1 > 0), none written twice at a seam, and their
    bound is within the target."""
    from .test_truncation_rows import position_channels

    for table, ch in position_channels("u-shape", n=2, z1=0.4):
        for i in range(ch.grp.shape[0]):
            pts, bound, walked, status = select_points(2, table.env, ch.grp[i], ch.mu[i], ch.Q[i], ch.Vinv[i],
                                                       ch.mnorm[i], ch.ab[i], ch.lam[i], 0.4, 0.0, 1e-9)
            assert status == 0 and bound <= 1e-9
            assert walked > 3 * 4096 and _CHUNK < pts.shape[0] < walked
            assert np.all(pts[:, 2] == 0)
            assert np.all((pts[:, 1] > 0) | ((pts[:, 1] == 0) & (pts[:, 0] > 0)))
            assert np.unique(pts, axis=0).shape[0] == pts.shape[0]
