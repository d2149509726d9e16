"""Geometry of a planar 3-PRP manipulator: per-leg parameters, presets, TOML.

Leg i = 1, 2, 3 is the closed chain O-G-P-R-F-T of the paper (eq. 1)::

    T = a_i i_i + b_i j_i + c_i k_i + d_i l_i + e_i m_i

with ``i_i = u(alpha_i)``, ``j_i = u(alpha_i + beta_i)``,
``k_i = u(alpha_i + beta_i + gamma_i + phi)``,
``l_i = u(alpha_i + beta_i + gamma_i + phi + theta_i)``,
``m_i = u(phi + psi_i)`` and ``u(t) = [cos t, sin t]``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._toml import dumps_toml, load_spec, load_toml
from ..output import write_text
from ..errors import GeometryError, UnknownPresetError

__all__ = ["Geometry", "Region", "LENGTHS", "ANGLES", "GEOMETRY_PRESETS", "REGION_PRESETS"]

#: Per-leg length parameters (mm).
LENGTHS = ("a", "c", "e")
#: Per-leg angle parameters (degrees at the boundary, radians inside).
ANGLES = ("alpha", "beta", "gamma", "theta", "psi")

_LEG_KEYS = ("a_mm", "alpha_deg", "beta_deg", "gamma_deg", "theta_deg",
             "c_mm", "e_mm", "psi_deg", "stroke_mm")
#: Optional per-leg keys: the lead of the slider's screw (a cyclic screw error repeats with it).
_OPTIONAL_LEG_KEYS = ("lead_mm",)


def _triple(name: str, values: Any) -> tuple[float, float, float]:
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise GeometryError(f"{name}: expected three numbers, got {values!r}") from None
    if arr.shape != (3,):
        raise GeometryError(f"{name}: expected three values (one per leg), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise GeometryError(f"{name}: values must be finite, got {arr.tolist()}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True, slots=True)
class Geometry:
    """Immutable, validated per-leg parameters of a 3-PRP manipulator.

    Parameters
    ----------
    a, c, e : sequence of 3 float
        Link lengths of legs 1-3, mm.
    alpha, beta, gamma, theta, psi : sequence of 3 float
        Angles of legs 1-3, **degrees** (the paper's Tables 1-2; the constant
        part of gamma_i only, phi is added by the model).
    stroke : sequence of 3 (lo, hi) pairs
        Travel of the actuated slider b_i, mm, lo < hi.
    lead : sequence of 3 (float or None)
        Lead p_i of each slider's lead screw, mm (> 0), or None where it is
        not known: the cyclic screw error ``cyclic_i`` repeats with it and
        needs it (optional; the kinematics do not use it).
    name : str
        Label used in reports.

    Notes
    -----
    :meth:`rad` gives the angles in radians as arrays of shape (3,); the
    kinematics work in radians only.
    """

    a: tuple[float, float, float]
    alpha: tuple[float, float, float]
    beta: tuple[float, float, float]
    gamma: tuple[float, float, float]
    theta: tuple[float, float, float]
    c: tuple[float, float, float]
    e: tuple[float, float, float]
    psi: tuple[float, float, float]
    stroke: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    name: str = "custom"
    lead: tuple = (None, None, None)
    _arrays: dict = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        for key in LENGTHS + ANGLES:
            object.__setattr__(self, key, _triple(key, getattr(self, key)))
        try:
            stroke = np.asarray(self.stroke, dtype=float)
        except (TypeError, ValueError):
            raise GeometryError(f"stroke: expected three [lo, hi] pairs, got {self.stroke!r}") from None
        if stroke.shape != (3, 2):
            raise GeometryError(f"stroke: expected three [lo, hi] pairs, got shape {stroke.shape}")
        if not np.all(np.isfinite(stroke)):
            raise GeometryError("stroke: values must be finite")
        for i, (lo, hi) in enumerate(stroke, start=1):
            if not lo < hi:
                raise GeometryError(f"stroke of leg {i}: lower limit {lo} mm must be below upper limit {hi} mm")
        object.__setattr__(self, "stroke", tuple((float(lo), float(hi)) for lo, hi in stroke))
        object.__setattr__(self, "lead", _leads(self.lead))
        arrays = {key: np.array(getattr(self, key)) for key in LENGTHS}
        arrays.update({key: np.deg2rad(getattr(self, key)) for key in ANGLES})
        arrays["stroke"] = stroke
        arrays["lead"] = np.array([np.nan if p is None else p for p in self.lead])
        for arr in arrays.values():
            arr.setflags(write=False)
        object.__setattr__(self, "_arrays", arrays)

    def rad(self, key: str) -> np.ndarray:
        """Parameter ``key`` as a read-only array of shape (3,): mm, or radians for angles."""
        return self._arrays[key]

    @property
    def stroke_mm(self) -> np.ndarray:
        """Strokes as a read-only array of shape (3, 2), mm."""
        return self._arrays["stroke"]

    @property
    def lead_mm(self) -> np.ndarray:
        """Leads of the sliders' screws as a read-only array of shape (3,), mm; NaN where not known."""
        return self._arrays["lead"]

    def replace(self, **changes: Any) -> "Geometry":
        """Return a copy with some parameters changed (degrees for angles)."""
        values = {key: getattr(self, key) for key in LENGTHS + ANGLES + ("stroke", "name", "lead")}
        values.update(changes)
        return Geometry(**values)

    def rotated(self, angle_deg: float) -> "Geometry":
        """The same manipulator with its whole base turned by ``angle_deg`` about O.

        A pose (T, phi) of this geometry becomes (R T, phi + angle_deg) of the
        rotated one. alpha_i turns every base-side vector; gamma_i loses the
        angle again because k_i and l_i already turn with phi.
        """
        return self.replace(alpha=np.add(self.alpha, angle_deg), gamma=np.subtract(self.gamma, angle_deg),
                            name=f"{self.name} rotated {angle_deg:g} deg")

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_preset(cls, name: str) -> "Geometry":
        """One of the two reference geometries: ``u-shape`` or ``delta-shape`` (our link lengths; the paper gives none)."""
        try:
            table = GEOMETRY_PRESETS[name]
        except KeyError:
            known = ", ".join(GEOMETRY_PRESETS)
            raise UnknownPresetError(f"unknown geometry preset {name!r} (known: {known})") from None
        return cls.from_dict(table, source=f"preset {name}")

    @classmethod
    def from_dict(cls, document: dict[str, Any], source: str = "geometry") -> "Geometry":
        """Build from the TOML layout: ``name`` and three ``[[leg]]`` tables.

        Each leg table holds ``a_mm, alpha_deg, beta_deg, gamma_deg, theta_deg,
        c_mm, e_mm, psi_deg, stroke_mm = [lo, hi]`` and optionally
        ``lead_mm``, the lead of the slider's screw (> 0).
        """
        legs = document.get("leg")
        if not isinstance(legs, list) or len(legs) != 3 or not all(isinstance(g, dict) for g in legs):
            raise GeometryError(f"{source}: expected exactly three [[leg]] tables")
        unknown = sorted(set(document) - {"name", "leg"})
        if unknown:
            raise GeometryError(f"{source}: unknown key(s) {', '.join(unknown)} (expected name and [[leg]])")
        values: dict[str, list] = {key: [] for key in _LEG_KEYS}
        for i, leg in enumerate(legs, start=1):
            extra = sorted(set(leg) - set(_LEG_KEYS) - set(_OPTIONAL_LEG_KEYS))
            if extra:
                hint = " (angles are given in degrees as *_deg, lengths in mm as *_mm)"
                raise GeometryError(f"{source}: leg {i}: unknown key(s) {', '.join(extra)}{hint}")
            missing = [key for key in _LEG_KEYS if key not in leg and key != "theta_deg"]
            if missing:
                raise GeometryError(f"{source}: leg {i}: missing {', '.join(missing)}")
            for key in _LEG_KEYS:
                values[key].append(leg.get(key, 0.0))
        for key in ("a_mm", "alpha_deg", "beta_deg", "gamma_deg", "theta_deg", "c_mm", "e_mm", "psi_deg"):
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values[key]):
                raise GeometryError(f"{source}: {key} must be a number in every leg")
        try:
            lead = _leads([leg.get("lead_mm") for leg in legs])
        except GeometryError as exc:
            raise GeometryError(f"{source}: {exc}") from None
        return cls(
            a=values["a_mm"], alpha=values["alpha_deg"], beta=values["beta_deg"],
            gamma=values["gamma_deg"], theta=values["theta_deg"], c=values["c_mm"],
            e=values["e_mm"], psi=values["psi_deg"], stroke=values["stroke_mm"],
            name=str(document.get("name", "custom")), lead=lead,
        )

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "Geometry":
        """Read a geometry TOML file (layout of :meth:`from_dict`)."""
        return cls.from_dict(load_toml(path), source=str(path))

    @classmethod
    def load(cls, spec: "str | os.PathLike | Geometry") -> "Geometry":
        """A preset name, a TOML path or a Geometry, as the CLI's ``--geometry`` takes."""
        return load_spec(cls, spec, GEOMETRY_PRESETS)

    def to_dict(self) -> dict[str, Any]:
        """The TOML layout of :meth:`from_dict`."""
        legs = []
        for i in range(3):
            legs.append({
                "a_mm": self.a[i], "alpha_deg": self.alpha[i], "beta_deg": self.beta[i],
                "gamma_deg": self.gamma[i], "theta_deg": self.theta[i], "c_mm": self.c[i],
                "e_mm": self.e[i], "psi_deg": self.psi[i], "stroke_mm": list(self.stroke[i]),
            })
            if self.lead[i] is not None:
                legs[-1]["lead_mm"] = self.lead[i]
        return {"name": self.name, "leg": legs}

    def to_toml(self, path: str | os.PathLike) -> None:
        """Write the geometry as TOML (atomically)."""
        header = "prp3mc geometry: lengths in mm, angles in degrees"
        write_text(path, dumps_toml(self.to_dict(), header=header))


@dataclass(frozen=True, slots=True)
class Region:
    """A rectangular test region of the workspace at constant orientation.

    Parameters
    ----------
    x_mm, y_mm : (lo, hi)
        Extent of the region, mm.
    phi_deg : float
        Platform orientation, degrees.
    """

    x_mm: tuple[float, float]
    y_mm: tuple[float, float]
    phi_deg: float = 0.0

    def __post_init__(self) -> None:
        for key in ("x_mm", "y_mm"):
            lo, hi = _pair(key, getattr(self, key))
            object.__setattr__(self, key, (lo, hi))
        if not np.isfinite(self.phi_deg):
            raise GeometryError("phi_deg must be finite")
        object.__setattr__(self, "phi_deg", float(self.phi_deg))

    @classmethod
    def from_preset(cls, name: str) -> "Region":
        """The test region of a reference geometry (the paper's 80 mm x 80 mm square at phi = 0)."""
        try:
            return cls(**REGION_PRESETS[name])
        except KeyError:
            known = ", ".join(REGION_PRESETS)
            raise UnknownPresetError(f"no test region for {name!r} (known: {known})") from None

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "Region":
        """Read a region TOML file: ``x_mm = [lo, hi]``, ``y_mm = [lo, hi]``, ``phi_deg`` (``prp3mc init region``)."""
        doc = load_toml(path)
        doc.pop("name", None)
        unknown = sorted(set(doc) - {"x_mm", "y_mm", "phi_deg"})
        if unknown or not {"x_mm", "y_mm"} <= set(doc):
            raise GeometryError(f"{path}: a region file holds x_mm = [lo, hi], y_mm = [lo, hi] and phi_deg "
                                f"(optional name); " + (f"unknown key(s) {', '.join(unknown)}" if unknown
                                                        else "x_mm or y_mm is missing"))
        try:
            return cls(**doc)
        except (TypeError, ValueError) as exc:
            raise GeometryError(f"{path}: {exc}") from None

    @classmethod
    def load(cls, spec: "str | os.PathLike | Region") -> "Region":
        """A preset name (a reference geometry's test region), a region TOML path or a Region, as ``--region`` takes."""
        return load_spec(cls, spec, REGION_PRESETS)

    def grid(self, n: int | tuple[int, int]) -> np.ndarray:
        """Poses on an ``ny x nx`` grid, shape (ny, nx, 3): x mm, y mm, phi deg."""
        nx, ny = (n, n) if np.isscalar(n) else n
        if nx < 1 or ny < 1:
            raise GeometryError("grid size must be at least 1")
        x = np.linspace(*self.x_mm, int(nx))
        y = np.linspace(*self.y_mm, int(ny))
        X, Y = np.meshgrid(x, y)
        return np.stack([X, Y, np.full_like(X, self.phi_deg)], axis=-1)


def _leads(values: Any) -> tuple:
    """Three screw leads, each a positive finite float (mm) or None."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__") or len(values) != 3:
        raise GeometryError(f"lead_mm: expected one value (or none) per leg, got {values!r}")
    out = []
    for i, p in enumerate(values, start=1):
        if p is not None and (isinstance(p, bool) or not isinstance(p, (int, float, np.floating, np.integer))
                              or not np.isfinite(p) or not p > 0):
            raise GeometryError(f"lead_mm of leg {i}: the lead of a screw must be a number > 0 mm, got {p!r}")
        out.append(None if p is None else float(p))
    return tuple(out)


def _pair(key: str, values: Any) -> tuple[float, float]:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)) or not arr[0] < arr[1]:
        raise GeometryError(f"{key}: expected finite [lo, hi] with lo < hi, got {values!r}")
    return float(arr[0]), float(arr[1])


def _preset(name, rows):
    keys = ("a_mm", "alpha_deg", "beta_deg", "gamma_deg", "c_mm", "e_mm", "psi_deg", "stroke_mm")
    return {"name": name, "leg": [dict(zip(keys, row), theta_deg=0.0) for row in rows]}


#: The reference geometries (link lengths chosen by us: the paper gives none).
GEOMETRY_PRESETS: dict[str, dict[str, Any]] = {
    "u-shape": _preset("u-shape", [
        (140.0, 180.0, -90.0, -90.0, 40.0, 10.0, 180.0, [0.0, 200.0]),
        (140.0, 0.0, 90.0, 90.0, 40.0, 10.0, 0.0, [0.0, 200.0]),
        (180.0, 90.0, -90.0, -90.0, 40.0, 10.0, 90.0, [-100.0, 100.0]),
    ]),
    "delta-shape": _preset("delta-shape", [
        (0.0, 0.0, 120.0, -90.0, 30.0, 20.0, 210.0, [0.0, 200.0]),
        (0.0, 0.0, 60.0, 90.0, 30.0, 20.0, -30.0, [0.0, 200.0]),
        (240.0, 90.0, -90.0, -90.0, 30.0, 20.0, 90.0, [-100.0, 100.0]),
    ]),
}

#: Test regions of the reference geometries (the paper's 80 mm x 80 mm square, phi = 0).
REGION_PRESETS: dict[str, dict[str, Any]] = {
    "u-shape": {"x_mm": (-40.0, 40.0), "y_mm": (60.0, 140.0), "phi_deg": 0.0},
    "delta-shape": {"x_mm": (-40.0, 40.0), "y_mm": (120.0, 200.0), "phi_deg": 0.0},
}
