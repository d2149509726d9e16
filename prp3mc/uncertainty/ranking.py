"""Sobol indices of every input and group ranked next to its share of the exact worst case.

Two views of the same budget at the same poses: the variance share
(:class:`~prp3mc.uncertainty.sobol.SobolResult`) and the part of the maximum
error at the maximising vertex (:class:`~prp3mc.uncertainty.worstcase.WorstCase`).
The ranking frame uses the result vocabulary of :mod:`prp3mc._result`
(``output``, ``name``, ``kind``, the indices ``S1``, ``ST`` and their
half-widths ``S1_conf``, ``ST_conf`` as in :meth:`SobolResult.to_frame`), its
worst-case columns in the boundary unit of the output (``df.attrs["unit"]``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..errors import BudgetError
from ..units import OUTPUT_UNITS
from .budget import parse_input
from .sobol import SobolResult
from .worstcase import WorstCase

__all__ = ["ranking"]


def _term_map(result: SobolResult, wc: WorstCase) -> np.ndarray:
    """(K, T) map of worst-case terms to names; a row of NaN where a name has no contribution.

    A clearance term rho_i cos(zeta_i - omega_i) belongs to a name holding both
    rho_i and zeta_i (clearance_i); rho_i and zeta_i alone, and groups that
    split a clearance, get NaN.
    """
    T = len(wc.terms)
    out = np.zeros((len(result.names), T))
    for k, name in enumerate(result.names):
        members = set(result.groups.get(name, (name,)))
        for t, term in enumerate(wc.terms):
            family, leg = parse_input(term)
            needs = {term, f"zeta_{leg + 1}"} if family == "rho" else {term}
            if needs <= members:
                out[k, t] = 1.0
            elif needs & members:
                out[k] = np.nan
                break
    return out


def ranking(sobol_result: SobolResult, worst_case_result: WorstCase, output: str = "position",
            index=None) -> pd.DataFrame:
    """Sobol indices of every input and group next to its share of the worst case.

    Parameters
    ----------
    sobol_result : SobolResult
    worst_case_result : WorstCase
        At the same poses and for the same budget.
    output : {"position", "x", "y", "phi"}
        The Sobol output, and the worst-case quantity it is ranked against.
    index : int or tuple, optional
        A pose of the batch; None aggregates over all poses (a region).

    Returns
    -------
    DataFrame
        One row per input and group, sorted by ST descending: output, name,
        kind, S1, S1_conf, ST, ST_conf, worst_case_contribution (mm, or deg
        for phi), worst_case_share. A group's contribution is the sum of its
        terms' contributions at the maximising vertex. The clearance term
        rho_i cos(zeta_i - omega_i) carries rho_i and zeta_i together, so its
        contribution is reported on ``clearance_i`` and rho_i, zeta_i (and
        any group holding only one of them) show NaN.

        For a region (``index=None``): S1 and ST are means over the poses,
        S1_conf and ST_conf the largest half-widths, ST_min and ST_max the
        range of ST; the worst-case contribution and share are those at the
        pose where the worst case of ``output`` is largest (the pose that
        sets the region's guarantee; its pose is in ``df.attrs["worst_pose"]``),
        worst_case_share_max the largest share over the poses and
        worst_case_share_mean the mean share over the poses (the same basis
        as S1 and ST; ``df.attrs["n_poses"]`` poses).
    """
    r, wc = sobol_result, worst_case_result
    if output not in r.outputs:
        raise BudgetError(f"output {output!r} is not in the Sobol result (has {', '.join(r.outputs)})")
    if r.poses.shape != wc.poses.shape or not np.allclose(r.poses, wc.poses):
        raise BudgetError("ranking needs the Sobol result and the worst case at the same poses")
    if tuple(wc.inputs) != tuple(r.names[:len(wc.inputs)]):
        raise BudgetError("ranking needs the Sobol result and the worst case of the same budget")
    o = r.outputs.index(output)
    contrib = np.einsum("...t,kt->...k", wc.contribution[output], _term_map(r, wc))    # (..., K)
    total = wc.value(output)[..., None]
    share = np.divide(contrib, total, out=np.zeros_like(contrib), where=total > 0)
    share = np.where(np.isnan(contrib), np.nan, share)
    idx = {"S1": r.S1[..., o, :], "S1_conf": r.S1_conf[..., o, :], "ST": r.ST[..., o, :],
           "ST_conf": r.ST_conf[..., o, :]}
    frame = {"output": output, "name": list(r.names), "kind": list(r.kinds)}
    if index is not None or r.poses.ndim == 1:
        at = () if index is None else index
        frame.update({key: value[at] for key, value in idx.items()})
        frame.update(worst_case_contribution=contrib[at], worst_case_share=share[at])
        df = pd.DataFrame(frame)
        df.attrs["pose"] = r.poses[at].tolist()
    else:
        K = len(r.names)
        flat = {key: value.reshape(-1, K) for key, value in idx.items()}
        worst = int(np.argmax(wc.value(output).reshape(-1)))
        frame.update(S1=flat["S1"].mean(0), S1_conf=flat["S1_conf"].max(0), ST=flat["ST"].mean(0),
                     ST_conf=flat["ST_conf"].max(0), ST_min=flat["ST"].min(0), ST_max=flat["ST"].max(0),
                     worst_case_contribution=contrib.reshape(-1, K)[worst],
                     worst_case_share=share.reshape(-1, K)[worst],
                     worst_case_share_max=share.reshape(-1, K).max(0),
                     worst_case_share_mean=share.reshape(-1, K).mean(0))
        df = pd.DataFrame(frame)
        df.attrs["worst_pose"] = r.poses.reshape(-1, 3)[worst].tolist()
        df.attrs["n_poses"] = len(flat["ST"])
    df.attrs["unit"] = OUTPUT_UNITS[output]
    return df.sort_values("ST", ascending=False, kind="stable").reset_index(drop=True)
