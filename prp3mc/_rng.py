"""One randomness convention for every stochastic function (Scientific Python SPEC 7).

Every stochastic public function takes ``rng: None | int | numpy.random.Generator``
and calls :func:`resolve_rng` once. The result records the integer seed that
was actually used, also when a Generator was handed in (a seed is then drawn
from it), so that any result can be reproduced from its record.

Independent streams inside one computation (blocks, bootstrap, configurations
of a study) come from :func:`child_seed`: a SeedSequence keyed by the root
seed and a stream key, so that results never depend on chunking, workers or
the order of evaluation.
"""

from __future__ import annotations

import numbers

import numpy as np

from .errors import Prp3mcError

__all__ = ["RngLike", "resolve_rng", "child_seed", "check_seed", "fresh_seed", "MAX_SEED"]

#: Seeds are recorded as non-negative integers below 2**63 (JSON- and int64-safe).
MAX_SEED = 2**63 - 1

RngLike = "None | int | np.random.Generator"


def fresh_seed() -> int:
    """A fresh seed from the operating system's entropy, in [0, 2**63)."""
    return int(np.random.SeedSequence().entropy % (MAX_SEED + 1))


def check_seed(seed) -> int:
    """Validate a user's seed: a non-negative integer below 2**63.

    Raises
    ------
    Prp3mcError
        One line naming the bad value.
    """
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise Prp3mcError(f"seed must be a non-negative integer, got {seed!r}")
    if not 0 <= int(seed) <= MAX_SEED:
        raise Prp3mcError(f"seed must be a non-negative integer below 2**63, got {seed}")
    return int(seed)


def resolve_rng(rng: "None | int | np.random.Generator" = None) -> tuple[int, np.random.Generator]:
    """Turn an ``rng`` argument into ``(seed, Generator)``.

    Parameters
    ----------
    rng : None, int or numpy.random.Generator
        None: a fresh seed from the OS. int: that seed. Generator: a seed is
        drawn from it (so the caller's stream advances and the result is
        reproducible from the recorded seed).

    Returns
    -------
    seed : int
        The integer seed used, in [0, 2**63); record it in the result.
    generator : numpy.random.Generator
        ``numpy.random.default_rng(seed)``.
    """
    if isinstance(rng, np.random.Generator):
        seed = int(rng.integers(0, MAX_SEED, dtype=np.int64, endpoint=True))
    elif rng is None:
        seed = fresh_seed()
    else:
        seed = check_seed(rng)
    return seed, np.random.default_rng(seed)


def child_seed(seed: int, *key: int) -> int:
    """An independent seed for stream ``key`` under root ``seed``, in [0, 2**63).

    ``child_seed(s, 1)`` and ``child_seed(s, 2)`` are statistically independent
    streams; the same arguments always give the same seed.
    """
    state = np.random.SeedSequence([int(seed), *map(int, key)]).generate_state(1, np.uint64)[0]
    return int(state >> np.uint64(1))
