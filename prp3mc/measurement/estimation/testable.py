"""What a campaign tests: the repeatable fraction's estimate, and why the rest is not testable.

The repeatable fraction r and the dispersion channels compare the visits of
a pose; a campaign that visits every pose once (a laser tracker's sweep)
tests the systematic channels only (:data:`ONE_VISIT` says so wherever a
channel is left untested). Effects the campaign cannot test have a reason:
a missing column or lead (:meth:`~prp3mc.model.effects.Effect.untestable`),
a signature in the nuisances' span, or drift without a time column.
"""

from __future__ import annotations

from .likelihood import Engine, Fit

__all__ = ["ONE_VISIT", "repeatability", "not_testable"]

#: Why a one-visit campaign tests no dispersion.
ONE_VISIT = ("no pose measured twice: the dispersion channels (spreads, the repeatable fraction, the repeat "
             "scatter) compare repeats; visit some poses again to test them")


def repeatability(engine: Engine, fit: Fit) -> dict:
    """The ``repeatability`` entry: the fitted repeatable fraction and its 95 % interval, or why it is not tested.

    Returns
    -------
    dict
        ``repeatable_fraction`` and ``ci95``; both None, with ``not_testable``
        (:data:`ONE_VISIT`), when no pose is measured twice.
    """
    if not engine.repeats:
        return {"repeatable_fraction": None, "ci95": None, "not_testable": ONE_VISIT}
    return {"repeatable_fraction": fit.r, "ci95": list(engine.r_interval(fit))}


def not_testable(engine: Engine) -> dict:
    """Effects (and drift, the repeatability) the campaign cannot test, name -> the reason (missing columns,
    confounded with a nuisance, drift without time, no repeats)."""
    out = dict(engine.not_testable)
    out.update({n: f"confounded with {with_}" for n, with_ in engine.confounded.items()})
    if engine.time_source != "time_s":
        out["drift"] = "no time_s column: drift fitted against row order"
    if not engine.repeats:
        out["repeatability"] = ONE_VISIT
    return out
