"""Catalogue-style probability laws of single error inputs.

Every law maps uniform numbers to values through its inverse CDF
(:meth:`Law.ppf`), so Monte Carlo, quasi-Monte Carlo and SALib's Sobol
sequences all sample through one path, and common random numbers are free.
Values are in the input's boundary unit (mm or degrees).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

import numpy as np
from scipy import integrate, special

from ..errors import BudgetError

__all__ = ["Law", "Uniform", "Normal", "TruncNormal", "Triangular", "Disc", "Discrete", "law_from_dict", "LAWS",
           "angle_moments", "MAX_K_SIGMA", "MIN_CPK"]


#: Largest k of a mean ± k·sd bound (beyond it the bound says nothing about a real part).
MAX_K_SIGMA = 100.0
#: Smallest process capability of a truncated normal (below it the parent sd overflows the tolerance).
MIN_CPK = 0.01


def _finite(law: str, **values: float) -> None:
    for key, value in values.items():
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise BudgetError(f"{law} law: {key} must be a finite number, got {value!r}")


def angle_moments(law: "Law") -> np.ndarray:
    """Trigonometric moments of an angle law (degrees), by quadrature of its ppf.

    Returns
    -------
    ndarray, shape (5,)
        ``E[cos t], E[sin t], E[cos² t], E[sin² t], E[sin t cos t]``.
    """
    def expect(fn):
        return integrate.quad(lambda u: fn(np.deg2rad(law.ppf(u))), 0.0, 1.0, limit=200)[0]

    return np.array([expect(np.cos), expect(np.sin), expect(lambda t: np.cos(t) ** 2),
                     expect(lambda t: np.sin(t) ** 2), expect(lambda t: np.sin(t) * np.cos(t))])


class Law:
    """Base of the laws; subclasses are frozen dataclasses."""

    kind: ClassVar[str]
    #: Parameters that scale with the variable (see :meth:`scaled`).
    scale_params: ClassVar[tuple[str, ...]] = ()

    def scaled(self, factor: float) -> "Law":
        """The law of ``factor * X`` for a factor >= 0 (a wider or narrower spread)."""
        if not (math.isfinite(factor) and factor >= 0):
            raise BudgetError(f"a law can only be scaled by a finite factor >= 0, got {factor}")
        spec = self.to_dict()
        spec.pop("law")
        for key in self.scale_params:
            spec[key] = [v * factor for v in spec[key]] if isinstance(spec[key], list) else spec[key] * factor
        return type(self)(**spec)

    def ppf(self, u: np.ndarray) -> np.ndarray:
        """Inverse CDF at ``u`` in [0, 1), any shape."""
        raise NotImplementedError

    @property
    def mean(self) -> float:
        raise NotImplementedError

    @property
    def var(self) -> float:
        raise NotImplementedError

    @property
    def support(self) -> tuple[float, float]:
        """Smallest interval holding all the probability (may be infinite)."""
        raise NotImplementedError

    @property
    def bounded(self) -> bool:
        lo, hi = self.support
        return math.isfinite(lo) and math.isfinite(hi)

    def bounds(self, k_sigma: float | None = None) -> tuple[float, float]:
        """Interval for the worst case: the support, or mean ± k_sigma·sd if unbounded."""
        if self.bounded:
            return self.support
        if k_sigma is None:
            raise BudgetError(f"{self.kind} law is unbounded: give k_sigma to bound it as mean ± k·sd")
        if not 0 < k_sigma <= MAX_K_SIGMA:
            raise BudgetError(f"k_sigma must lie in (0, {MAX_K_SIGMA:g}], got {k_sigma}")
        sd = math.sqrt(self.var)
        return self.mean - k_sigma * sd, self.mean + k_sigma * sd

    def span(self) -> tuple[float, float]:
        """Where the law's values lie in practice: its support, or mean ± 6 sd if unbounded."""
        if self.bounded:
            return self.support
        try:
            sd = math.sqrt(self.var)
        except OverflowError:  # sd**2 beyond float range
            return -math.inf, math.inf
        return self.mean - 6.0 * sd, self.mean + 6.0 * sd

    def to_dict(self) -> dict[str, Any]:
        return {"law": self.kind, **asdict(self)}


@dataclass(frozen=True, slots=True)
class Uniform(Law):
    """Uniform on [lo, hi]."""

    lo: float
    hi: float
    kind: ClassVar[str] = "uniform"
    scale_params: ClassVar[tuple[str, ...]] = ("lo", "hi")

    def __post_init__(self):
        _finite("uniform", lo=self.lo, hi=self.hi)
        if not self.lo <= self.hi:
            raise BudgetError(f"uniform law: lo = {self.lo} must not exceed hi = {self.hi}")

    def ppf(self, u):
        return self.lo + (self.hi - self.lo) * np.asarray(u)

    mean = property(lambda self: 0.5 * (self.lo + self.hi))
    var = property(lambda self: (self.hi - self.lo) ** 2 / 12.0)
    support = property(lambda self: (self.lo, self.hi))


@dataclass(frozen=True, slots=True)
class Normal(Law):
    """Normal with ``mean`` and standard deviation ``sd`` (unbounded)."""

    mu: float
    sd: float
    kind: ClassVar[str] = "normal"
    scale_params: ClassVar[tuple[str, ...]] = ("mu", "sd")

    def __post_init__(self):
        _finite("normal", mu=self.mu, sd=self.sd)
        if not self.sd >= 0:
            raise BudgetError(f"normal law: sd = {self.sd} must be >= 0")

    def ppf(self, u):
        return self.mu + self.sd * special.ndtri(np.asarray(u))

    mean = property(lambda self: self.mu)
    var = property(lambda self: self.sd**2)
    support = property(lambda self: (-math.inf, math.inf) if self.sd > 0 else (self.mu, self.mu))


@dataclass(frozen=True, slots=True)
class TruncNormal(Law):
    """Normal truncated to a tolerance ``center ± tol`` with capability ``cpk``.

    A centred process with Cpk has sd = tol / (3 Cpk); parts outside the
    tolerance are rejected, so the law is truncated there.
    """

    center: float
    tol: float
    cpk: float
    kind: ClassVar[str] = "truncnormal"
    scale_params: ClassVar[tuple[str, ...]] = ("center", "tol")

    def __post_init__(self):
        _finite("truncnormal", center=self.center, tol=self.tol, cpk=self.cpk)
        if not self.tol > 0 or not self.cpk >= MIN_CPK:
            raise BudgetError(f"truncnormal law: need tol > 0 and cpk >= {MIN_CPK:g}, got tol={self.tol}, "
                              f"cpk={self.cpk}")

    @property
    def sd_parent(self) -> float:
        return self.tol / (3.0 * self.cpk)

    def _dist(self):
        from scipy.stats import truncnorm  # only this law needs scipy.stats: imported when it is used
        z = 3.0 * self.cpk
        return truncnorm(-z, z, loc=self.center, scale=self.sd_parent)

    def ppf(self, u):
        z = 3.0 * self.cpk
        lo = special.ndtr(-z)
        return self.center + self.sd_parent * special.ndtri(lo + (1.0 - 2.0 * lo) * np.asarray(u))

    mean = property(lambda self: self.center)
    var = property(lambda self: float(self._dist().var()))
    support = property(lambda self: (self.center - self.tol, self.center + self.tol))


@dataclass(frozen=True, slots=True)
class Triangular(Law):
    """Triangular on [lo, hi] with peak at ``mode``."""

    lo: float
    mode: float
    hi: float
    kind: ClassVar[str] = "triangular"
    scale_params: ClassVar[tuple[str, ...]] = ("lo", "mode", "hi")

    def __post_init__(self):
        _finite("triangular", lo=self.lo, mode=self.mode, hi=self.hi)
        if not (self.lo <= self.mode <= self.hi and self.lo < self.hi):
            raise BudgetError(f"triangular law: need lo <= mode <= hi and lo < hi, got "
                              f"{self.lo}, {self.mode}, {self.hi}")

    def ppf(self, u):
        u = np.asarray(u)
        lo, m, hi = self.lo, self.mode, self.hi
        fc = (m - lo) / (hi - lo)
        return np.where(u < fc, lo + np.sqrt(u * (hi - lo) * (m - lo)),
                        hi - np.sqrt((1.0 - u) * (hi - lo) * (hi - m)))

    mean = property(lambda self: (self.lo + self.mode + self.hi) / 3.0)
    var = property(lambda self: (self.lo**2 + self.mode**2 + self.hi**2 - self.lo * self.mode
                                 - self.lo * self.hi - self.mode * self.hi) / 18.0)
    support = property(lambda self: (self.lo, self.hi))


@dataclass(frozen=True, slots=True)
class Disc(Law):
    """Radius of a point uniform over a disc of ``radius``: rho = radius·sqrt(U).

    For a clearance input ``rho_i``: with a uniform contact angle ``zeta_i``
    the clearance displacement is uniform over the disc.
    """

    radius: float
    kind: ClassVar[str] = "disc"
    scale_params: ClassVar[tuple[str, ...]] = ("radius",)

    def __post_init__(self):
        _finite("disc", radius=self.radius)
        if not self.radius >= 0:
            raise BudgetError(f"disc law: radius = {self.radius} must be >= 0")

    def ppf(self, u):
        return self.radius * np.sqrt(np.asarray(u))

    mean = property(lambda self: 2.0 * self.radius / 3.0)
    var = property(lambda self: self.radius**2 / 18.0)
    support = property(lambda self: (0.0, self.radius))


@dataclass(frozen=True, slots=True)
class Discrete(Law):
    """Discrete catalogue classes: ``values`` with probabilities ``weights``."""

    values: tuple[float, ...]
    weights: tuple[float, ...]
    kind: ClassVar[str] = "discrete"
    scale_params: ClassVar[tuple[str, ...]] = ("values",)

    def __post_init__(self):
        try:
            values = tuple(float(v) for v in self.values)
            weights = tuple(float(w) for w in self.weights)
        except (TypeError, ValueError):
            raise BudgetError(f"discrete law: values and weights must be numbers, got values={self.values!r}, "
                              f"weights={self.weights!r}") from None
        if not values or len(values) != len(weights):
            raise BudgetError("discrete law: values and weights must be non-empty and of equal length")
        if not all(math.isfinite(v) for v in values + weights) or min(weights) < 0 or sum(weights) <= 0:
            raise BudgetError("discrete law: values must be finite and weights >= 0 with a positive sum")
        order = np.argsort(values)
        scaled = [w / max(weights) for w in weights]   # their sum may overflow (1e308 each) or underflow
        object.__setattr__(self, "values", tuple(values[i] for i in order))
        object.__setattr__(self, "weights", tuple(scaled[i] / sum(scaled) for i in order))

    def ppf(self, u):
        cdf = np.cumsum(self.weights)
        cdf[-1] = 1.0
        idx = np.searchsorted(cdf, np.asarray(u), side="right")
        return np.asarray(self.values)[np.minimum(idx, len(self.values) - 1)]

    mean = property(lambda self: float(np.dot(self.values, self.weights)))
    var = property(lambda self: float(np.dot(np.square(np.subtract(self.values, self.mean)), self.weights)))
    support = property(lambda self: (self.values[0], self.values[-1]))

    def to_dict(self):
        return {"law": self.kind, "values": list(self.values), "weights": list(self.weights)}


LAWS: dict[str, type[Law]] = {cls.kind: cls for cls in (Uniform, Normal, TruncNormal, Triangular, Disc, Discrete)}


def law_from_dict(spec: dict[str, Any], where: str) -> Law:
    """Build a law from ``{"law": kind, **parameters}``; errors name ``where``."""
    spec = dict(spec)
    if "law" not in spec:
        raise BudgetError(f"{where}: {_inline(spec)} is not a law: give law = \"uniform\", lo = ..., hi = ... "
                          f"(laws: {', '.join(LAWS)}) or catalogue = \"dotted.key\"")
    kind = spec.pop("law")
    if not isinstance(kind, str) or kind not in LAWS:
        raise BudgetError(f"{where}: unknown law {kind!r} (known: {', '.join(LAWS)})")
    cls = LAWS[kind]
    names = [f.name for f in fields(cls)]
    missing = [n for n in names if n not in spec]
    extra = sorted(set(spec) - set(names))
    if missing or extra:
        expect = ", ".join(names)
        raise BudgetError(f"{where}: {kind} law takes {expect}" + (f"; missing {', '.join(missing)}" if missing else "")
                          + (f"; unknown {', '.join(extra)}" if extra else ""))
    try:
        return cls(**spec)
    except BudgetError as exc:
        raise BudgetError(f"{where}: {exc}") from None
    except TypeError as exc:
        raise BudgetError(f"{where}: {exc}") from None


def _inline(spec: dict[str, Any]) -> str:
    """``{a = 1, b = 2}``: a table as the user wrote it, shortened."""
    text = "{" + ", ".join(f"{k if str(k).isidentifier() else repr(k)} = {v!r}" for k, v in spec.items()) + "}"
    return text if len(text) <= 60 else text[:57] + "...}"
