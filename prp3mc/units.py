"""One home for unit conversions, confidence levels and the names of outputs.

Units are mm and degrees at every boundary, radians inside; reports show
µm and arcsec, spelled so.
"""

from __future__ import annotations

import math
import warnings

from .errors import Prp3mcWarning, SpecError

__all__ = ["RAD2DEG", "DEG2RAD", "MM2UM", "DEG2ARCSEC", "PPM", "POSE_OUTPUTS", "OUTPUTS", "OUTPUT_UNITS",
           "DISPLAY", "SPEC_UNITS", "spec_value", "z_value", "t_value", "Z95", "probability_text", "quantity_text"]

RAD2DEG = 180.0 / math.pi
DEG2RAD = math.pi / 180.0
MM2UM = 1e3
DEG2ARCSEC = 3600.0
#: Parts per million per unit of probability (exceedances in reports).
PPM = 1e6
#: A pose-error spec's unit, the larger unit it is mistyped in and the factor between them, by keyword: below 1
#: of its unit a spec warns (:func:`spec_value`, the one rule every entry point applies).
SPEC_UNITS = {"spec_position_um": ("µm", "mm", MM2UM), "spec_phi_arcsec": ("arcsec", "deg", DEG2ARCSEC)}


def spec_value(name: str, value) -> float:
    """The value of spec keyword ``name`` (a key of :data:`SPEC_UNITS`): a finite number > 0 in its unit (else
    SpecError); below 1 it is taken, with a warning, as a value typed in the larger unit (mm, deg)? The one rule
    of every entry point (:func:`prp3mc.exact_yield`, ``prp3mc allocate``, ``prp3mc yield``, a study's ``[spec]``)."""
    import numpy as np

    unit, big_unit, per_big = SPEC_UNITS[name]
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value) or value <= 0:
        raise SpecError(f"{name} must be a finite number > 0 {unit}, got {value!r}")
    if value < 1.0:
        warnings.warn(Prp3mcWarning(f"{name} = {value:g} {unit} is below 1 {unit}: a spec in {big_unit} typed as "
                                    f"{unit}? ({value:g} {big_unit} = {per_big * value:g} {unit})"), stacklevel=3)
    return float(value)

#: Components of the pose error, in order: rows of every J_q.
POSE_OUTPUTS = ("x", "y", "phi")
#: Every scalar output an analysis reports: the components and the position-error norm.
OUTPUTS = ("x", "y", "phi", "position")
#: Unit of each output at the boundary.
OUTPUT_UNITS = {"x": "mm", "y": "mm", "phi": "deg", "position": "mm"}
#: Display scale and unit of each output in reports: (factor from the boundary unit, unit).
DISPLAY = {"x": (MM2UM, "µm"), "y": (MM2UM, "µm"), "phi": (DEG2ARCSEC, "arcsec"), "position": (MM2UM, "µm")}


def z_value(level: float = 0.95) -> float:
    """Two-sided standard-normal quantile for a confidence ``level`` in (0, 1)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must lie in (0, 1), got {level}")
    from scipy.special import ndtri         # when used: the command line's parsers import no scipy
    return float(ndtri(0.5 + level / 2))  # scipy.stats.norm.ppf's own kernel, without importing scipy.stats


def t_value(level: float, df: int) -> float:
    """Two-sided Student t quantile with ``df`` degrees of freedom for a confidence ``level`` in (0, 1)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must lie in (0, 1), got {level}")
    from scipy.special import stdtrit
    return float(stdtrit(df, 0.5 + level / 2))  # scipy.stats.t.ppf's kernel, without importing scipy.stats


#: The 95 % two-sided normal quantile, ``z_value(0.95)`` written out (tests/test_lazy_imports.py checks it), so
#: that importing this module imports no scipy.
Z95 = 1.959963984540054


def probability_text(p: float, ci=None, se: float | None = None) -> str:
    """A probability as a reader of tolerance reports reads it: ppm below 1 %, % above; an interval ``ci``
    or a standard error ``se`` in the same unit.

    >>> probability_text(0.000815)
    '815 ppm'
    >>> probability_text(0.0528, (0.05, 0.055))
    '5.28 % [5, 5.5]'
    >>> probability_text(0.0528, se=0.0018)
    '5.28 ± 0.18 %'
    """
    scale, unit = (PPM, "ppm") if p < 0.01 else (100.0, "%")

    def number(v: float) -> str:  # three significant digits, never an exponent
        return f"{v:.0f}" if abs(v) >= 100 else f"{v:.3g}"
    if se is not None:
        spread = scale * se
        return f"{number(scale * p)} ± {spread:.0f} {unit}" if spread >= 10 else f"{number(scale * p)} ± {spread:.2g} {unit}"
    text = f"{number(scale * p)} {unit}"
    if ci is not None:
        text += f" [{number(scale * ci[0])}, {number(scale * ci[1])}]"
    return text


def quantity_text(value: float, unit: str, fmt: str = ".4g") -> str:
    """``value unit``, a dimensionless value (unit ``1``) without its unit and, when small, also in ppm.

    >>> quantity_text(0.0004874, "1")
    '4.874e-04 (487.4 ppm)'
    >>> quantity_text(0.012, "mm")
    '0.012 mm'
    """
    if unit != "1":
        return f"{value:{fmt}} {unit}"
    if value == 0 or abs(value) >= 0.01:
        return f"{value:{fmt}}"
    return f"{value:.3e} ({PPM * value:{fmt}} ppm)"
