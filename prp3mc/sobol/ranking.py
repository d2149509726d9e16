"""Sobol indices of every input and group ranked next to its share of the exact worst case.

Two views of the same budget at the same poses: the variance share
(:class:`~prp3mc.sobol.indices.SobolResult`) and the part of the maximum
error at the maximising vertex (:class:`~prp3mc.worstcase.envelope.WorstCaseResult`).
The ranking frame uses the result vocabulary of :mod:`prp3mc._result`
(``output``, ``name``, ``kind``, the indices ``S1``, ``ST``, the Shapley
effects ``Sh`` when computed, and their half-widths ``S1_conf``, ``ST_conf``,
``Sh_conf`` as in :meth:`SobolResult.to_frame`), its worst-case columns in the
boundary unit of the output (``df.attrs["unit"]``). A correlated budget has no
Sobol indices (NaN): its ranking is by the Shapley effects.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..errors import ParameterError
from ..units import OUTPUT_UNITS
from .indices import SobolResult
from ..worstcase.envelope import WorstCaseResult

__all__ = ["ranking"]


def _term_map(result: SobolResult, wc: WorstCaseResult) -> tuple[np.ndarray, list]:
    """(K + S, T) map of worst-case terms to names, and the S known shifts' terms (rows K onwards).

    A clearance term rho_i cos(zeta_i - omega_i) belongs to a name holding both
    rho_i and zeta_i (clearance_i); rho_i and zeta_i alone, and groups that
    split a clearance, get a row of NaN. A known shift (an offset, lead
    scale or cyclic screw error effect) varies with no factor: it gets a row of its own.
    """
    factors = wc.inputs
    needs, shifts = [], []
    for t, tl in enumerate(wc.model.term_laws):
        if tl.kind == "shift":
            shifts.append(t)
            needs.append(None)
        else:
            needs.append({factors[i] for i in tl.factors})
    out = np.zeros((len(result.names) + len(shifts), len(wc.terms)))
    for k, name in enumerate(result.names):
        members = set(result.groups.get(name, (name,)))
        for t, need in enumerate(needs):
            if need is None:
                continue
            if need <= members:
                out[k, t] = 1.0
            elif need & members:
                out[k] = np.nan
                break
    for j, t in enumerate(shifts):
        out[len(result.names) + j, t] = 1.0
    return out, [wc.terms[t] for t in shifts]


def ranking(sobol_result: SobolResult, worst_case_result: WorstCaseResult, output: str = "position",
            index=None) -> pd.DataFrame:
    """Sobol indices of every input and group next to its share of the worst case.

    Parameters
    ----------
    sobol_result : SobolResult
    worst_case_result : WorstCaseResult
        At the same poses and for the same budget.
    output : {"position", "x", "y", "phi"}
        The Sobol output, and the worst-case quantity it is ranked against.
    index : int or tuple, optional
        A pose of the batch; None aggregates over all poses (a region).

    Returns
    -------
    DataFrame
        One row per input and group, sorted by ST descending (by Sh for a
        correlated budget, ``df.attrs["sorted_by"]``): output, name,
        kind, S1, S1_conf, ST, ST_conf, Sh and Sh_conf (when the result has
        them), worst_case_contribution (mm, or deg
        for phi), worst_case_share. A group's contribution is the sum of its
        terms' contributions at the maximising vertex. The clearance term
        rho_i cos(zeta_i - omega_i) carries rho_i and zeta_i together, so its
        contribution is reported on ``clearance_i`` and rho_i, zeta_i (and
        any group holding only one of them) show NaN. The budget's known
        shifts (offset effects as ``offset_q_i``, ``scale_i``, ``cyclic_i``) follow with
        kind ``shift``: a systematic contribution to the worst case, no
        variance share (S1, ST NaN), last in the order.

        For a region (``index=None``): S1, ST and Sh are means over the poses,
        S1_conf, ST_conf and Sh_conf the largest half-widths, ST_min and ST_max the
        range of ST; the worst-case contribution and share are those at the
        pose where the worst case of ``output`` is largest (the pose that
        sets the region's guarantee; its pose is in ``df.attrs["worst_pose"]``),
        worst_case_share_max the largest share over the poses and
        worst_case_share_mean the mean share over the poses (the same basis
        as S1 and ST; ``df.attrs["n_poses"]`` poses).
    """
    r, wc = sobol_result, worst_case_result
    if output not in r.outputs:
        raise ParameterError(f"output {output!r} is not in the Sobol result (has {', '.join(r.outputs)})")
    if r.poses.shape != wc.poses.shape or not np.allclose(r.poses, wc.poses):
        raise ParameterError("ranking needs the Sobol result and the worst case at the same poses")
    if tuple(wc.inputs) != tuple(r.names[:len(wc.inputs)]):
        raise ParameterError("ranking needs the Sobol result and the worst case of the same budget")
    o = r.outputs.index(output)
    term_map, shifts = _term_map(r, wc)
    contrib = np.einsum("...t,kt->...k", wc.contribution[output], term_map)    # (..., K + S)
    total = wc.value(output)[..., None]
    share = np.divide(contrib, total, out=np.zeros_like(contrib), where=total > 0)
    share = np.where(np.isnan(contrib), np.nan, share)
    pad = np.full(r.S1.shape[:-2] + (len(shifts),), np.nan)
    keys = [k for stat in r.statistics for k in (stat, f"{stat}_conf")]
    idx = {key: np.concatenate([getattr(r, key)[..., o, :], pad], axis=-1) for key in keys}
    frame = {"output": output, "name": list(r.names) + shifts, "kind": list(r.kinds) + ["shift"] * len(shifts)}
    if index is not None or r.poses.ndim == 1:
        at = () if index is None else index
        frame.update({key: value[at] for key, value in idx.items()})
        frame.update(worst_case_contribution=contrib[at], worst_case_share=share[at])
        df = pd.DataFrame(frame)
        df.attrs["pose"] = r.poses[at].tolist()
    else:
        K = len(r.names) + len(shifts)
        flat = {key: value.reshape(-1, K) for key, value in idx.items()}
        worst = int(np.argmax(wc.value(output).reshape(-1)))
        frame.update({key: flat[key].max(0) if key.endswith("_conf") else flat[key].mean(0) for key in keys})
        frame.update(ST_min=flat["ST"].min(0), ST_max=flat["ST"].max(0),
                     worst_case_contribution=contrib.reshape(-1, K)[worst],
                     worst_case_share=share.reshape(-1, K)[worst],
                     worst_case_share_max=share.reshape(-1, K).max(0),
                     worst_case_share_mean=share.reshape(-1, K).mean(0))
        df = pd.DataFrame(frame)
        df.attrs["worst_pose"] = r.poses.reshape(-1, 3)[worst].tolist()
        df.attrs["n_poses"] = len(flat["ST"])
    df.attrs["unit"] = OUTPUT_UNITS[output]
    df.attrs["sorted_by"] = "Sh" if r.correlated else "ST"
    return df.sort_values(df.attrs["sorted_by"], ascending=False, kind="stable").reset_index(drop=True)
