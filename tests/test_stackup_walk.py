"""The lattice walk's shortcuts (prp3mc/stackup/truncation.py) give the bits of what they replace."""

from __future__ import annotations

import math

import numpy as np

from prp3mc.stackup.characteristic import envelope
from prp3mc.stackup.truncation import _BINS, _bin, _inverse_envelope, _only_inverse


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
