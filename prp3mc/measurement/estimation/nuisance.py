"""Nuisance parameters: properties of the measurement, never of the machine.

A campaign is measured in the instrument's frame, by an instrument that may
drift. Two nuisances are fitted in every model (null and alternative alike),
so they are profiled out of every test:

- **registration** (3 parameters): the planar rigid transform from the
  machine frame to the instrument frame, a rotation ``phi_r`` about the
  instrument's origin followed by a translation ``(t_x, t_y)``. Linear in
  the small angle, it adds to a measured pose ``(x, y, phi)``
  ``[t_x - phi_r y, t_y + phi_r x, phi_r]`` (phi_r in rad in the position
  rows); values are reported in mm, mm and deg.
- **drift** (3 parameters): a pose offset growing linearly in time from 0 at
  the first measurement to ``(d_x, d_y, d_phi)`` at the last, time being
  ``time_s`` (row order without it).

What the campaign cannot tell apart from these (an effect whose signature
lies in their span, such as a zero offset ``b_i`` on a campaign at constant
phi, which only translates every pose) is *confounded*: it cannot be tested
and is reported so, never named.
"""

from __future__ import annotations

import numpy as np

from ...errors import CampaignError
from ...units import DEG2RAD
from ..campaign.data import Campaign

__all__ = ["NUISANCE_NAMES", "NUISANCE_UNITS", "REGISTRATION", "DRIFT", "campaign_time", "nuisance_signatures",
           "listed_nuisances"]

#: Registration parameters, in signature column order.
REGISTRATION = ("registration_x", "registration_y", "registration_phi")
#: Drift parameters, in signature column order.
DRIFT = ("drift_x", "drift_y", "drift_phi")
NUISANCE_NAMES = REGISTRATION + DRIFT
NUISANCE_UNITS = dict(zip(NUISANCE_NAMES, ("mm", "mm", "deg") * 2))


def campaign_time(campaign: Campaign) -> tuple[np.ndarray, str]:
    """Time of each measurement as a fraction of the campaign, 0 at the earliest and 1 at the latest.

    Returns
    -------
    s : ndarray, shape (M,)
        From ``time_s`` if the campaign has it, else from row order.
    source : str
        ``"time_s"`` or ``"row order"``.

    Raises
    ------
    CampaignError
        ``time_s`` has a non-finite value.
    """
    extra = campaign.extra
    if "time_s" in extra.columns:
        t = np.asarray(extra["time_s"].to_numpy(), dtype=float)
        if not np.isfinite(t).all():
            r = int(np.flatnonzero(~np.isfinite(t))[0])
            raise CampaignError(f"{campaign.source}: row {r + 1}, column time_s: expected a finite number")
        source = "time_s"
    else:
        t, source = np.arange(campaign.n_measurements, dtype=float), "row order"
    span = t.max() - t.min() if t.size > 1 else 0.0   # rows may be stored in any order: time is time_s
    if span == 0:
        return np.zeros_like(t), source
    return (t - t.min()) / span, source


def nuisance_signatures(commanded: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Pose-error signatures of registration and drift, one per measurement.

    Parameters
    ----------
    commanded : ndarray, shape (M, 3)
        Commanded poses ``[x_mm, y_mm, phi_deg]`` (the machine-frame point the rotation moves).
    s : ndarray, shape (M,)
        Campaign time fraction (:func:`campaign_time`).

    Returns
    -------
    ndarray, shape (M, 3, 6)
        ``[dx mm, dy mm, dphi deg]`` per unit of each of :data:`NUISANCE_NAMES` (mm or deg).
    """
    M = commanded.shape[0]
    H = np.zeros((M, 3, 6))
    H[:, 0, 0] = H[:, 1, 1] = 1.0
    H[:, 0, 2] = -commanded[:, 1] * DEG2RAD
    H[:, 1, 2] = commanded[:, 0] * DEG2RAD
    H[:, 2, 2] = 1.0
    for k in range(3):
        H[:, k, 3 + k] = s
    return H


def listed_nuisances(engine, fit, alpha: float, named=()) -> tuple[tuple, dict]:
    """The ``nuisance`` entries of a fit (registration when fitted, drift when its LR test rejects) and the drift test.

    Drift is fitted in every model; it is *listed* only when the likelihood
    ratio against the fit without it (chi2(3)) rejects at ``alpha``. A
    nuisance that an alias of a named effect fits differently has the union
    of the intervals as its ``ci95``, the named model's own as
    ``ci95_named_model`` and each alias's fit under ``by_alias``.

    Parameters
    ----------
    engine : Engine
        The likelihood engine of the kept rows (:mod:`~prp3mc.measurement.estimation.likelihood`).
    fit : Fit
        The named model.
    alpha : float
        Level of the drift test.
    named : sequence of NamedEffect
        The named effects (their ``evidence["alias_fits"]`` hold each alias's nuisances).

    Returns
    -------
    entries : tuple of dict
        ``name``, value, unit and ``ci95`` of each listed nuisance.
    drift_test : dict
        ``lr, df, p, significant, time`` (``time_s`` or row order) and the drift ``values``.
    """
    entries = {}
    for name, entry in engine.nuisances(fit).items():
        entries[name] = {"name": name, **entry}
        alias = [{"effect": a, **f["nuisance"][name]} for e in named for a, f in e.evidence["alias_fits"].items()
                 if name in f.get("nuisance", {})]
        if alias:
            ci = entry["ci95"]
            lo = min([ci[0]] + [f["ci95"][0] for f in alias])
            hi = max([ci[1]] + [f["ci95"][1] for f in alias])
            entries[name].update(ci95=[lo, hi], ci95_named_model=list(ci), by_alias=alias)
    no_drift = engine.refit(fit.sys, fit.factors, start_r=fit.r,
                            nuis=tuple(j for j in fit.nuis if NUISANCE_NAMES[j] not in DRIFT))
    lr = max(2.0 * (fit.loglik - no_drift.loglik), 0.0)
    from scipy.stats import chi2  # imported when used: prp3mc --help imports this module
    p = float(chi2.sf(lr, 3))
    drift_test = {"lr": lr, "df": 3, "p": p, "significant": bool(p < alpha), "time": engine.time_source,
                  "values": {n: entries[n]["value"] for n in DRIFT}}
    listed = [n for n in REGISTRATION if n in entries] + (list(DRIFT) if drift_test["significant"] else [])
    return tuple(entries[n] for n in listed), drift_test
