"""P(either) by conditioning on two legs at the target: the channels summed again where only their bounds keep
P(either)'s bound above it (prp3mc.stackup.exceedance._conditioned), against the 3-D series.

Where a normal law sits in every leg the 3-D series of the cylinder serves and is the independent reference:
P_pos + P_phi - J by conditioning (its channels tightened) must agree with its P(either) within the sum of both
bounds, at specs where J's bracket closes to below 1e-9 so that P(either)'s bound is the channels' (the 1e-9
scale is then what is checked).
"""

import math

import numpy as np
import pytest
from scipy import special

from prp3mc import Geometry, exact_yield
from prp3mc.model.linear import linear_model
from prp3mc.stackup import exceedance
from prp3mc.stackup.characteristic import term_table
from prp3mc.units import DEG2ARCSEC, MM2UM

from .test_conditional import _paper_normal_encoders
from .test_yield import ARCSEC

POSES = np.array([[0.0, 100.0, 0.0], [25.0, 75.0, -3.0], [-30.0, 130.0, 2.0]])


def _conditioned(geometry, budget, S_um, Z_as, r, target=1e-9, workers=1):
    """_conditioned at every pose of ``r`` (all taken as still bracketed), with exact_yield's table and share."""
    m = linear_model(geometry, budget, r.poses)
    C, Ainv = m.columns.reshape(-1, 3, len(m.terms)), m.Ainv.reshape(-1, 3, 3)
    n_normal = sum(1 for tl in m.term_laws if tl.law is not None and tl.law.kind == "normal")
    share = 0.01 * target / max(n_normal, 1)
    table = term_table(m.term_laws, math.sqrt(2.0) * float(special.erfcinv(share)))
    N = C.shape[0]
    start = exceedance._Either(np.full(N, 0.5), np.ones(N), np.ones(N, bool), np.zeros(N, bool))
    return exceedance._conditioned(start, C=C, Ainv=Ainv, legs=np.array(m.legs), table=table, share=share,
                                   S=S_um / MM2UM, Z=Z_as * ARCSEC, target=target,
                                   position=(r.exceed_position, r.bound_position),
                                   phi=(r.exceed_phi, r.bound_phi), workers=workers)


@pytest.mark.parametrize("scale", [(1.0, 1.0), (1.2, 0.8)])
def test_tightened_channels_agree_with_the_joint_series_at_1e_9(scale):
    geometry, budget = Geometry.from_preset("u-shape"), _paper_normal_encoders()
    r0 = exact_yield(geometry, budget, POSES, spec_position_um=1.0, quantiles=False)
    S_um = float(np.median(r0.rss_position_mm)) * MM2UM * scale[0]
    Z_as = float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC * scale[1]
    r = exact_yield(geometry, budget, POSES, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False)
    assert not r.bracketed_any.any() and r.bound_any.max() <= 1e-9            # the 3-D series served
    e = _conditioned(geometry, budget, S_um, Z_as, r)
    assert e.conditioned.all() and not e.bracketed.any()
    assert np.all(np.abs(e.exceed - r.exceed_any) <= e.bound + r.bound_any), (e.exceed, r.exceed_any, e.bound)
    reached = e.bound <= 1e-9
    assert (reached & (r.exceed_position > 0)).any()     # at the target where J closes, both channels at work
    # the channels alone, at exact_yield's target, would have kept every such pose above half of it
    assert np.all((r.bound_position + r.bound_phi)[reached] > 0.5e-9)
    print(f"scale {scale}: P(either) {r.exceed_any}, conditioned bound {e.bound}, |cond - series| / bounds "
          f"{np.abs(e.exceed - r.exceed_any) / (e.bound + r.bound_any)}")


def test_tightened_channels_leave_every_bit_on_two_threads():
    geometry, budget = Geometry.from_preset("u-shape"), _paper_normal_encoders()
    r0 = exact_yield(geometry, budget, POSES, spec_position_um=1.0, quantiles=False)
    S_um = float(np.median(r0.rss_position_mm)) * MM2UM * 1.5
    Z_as = float(np.median(r0.rss_phi_deg)) * DEG2ARCSEC * 0.6
    r = exact_yield(geometry, budget, POSES, spec_position_um=S_um, spec_phi_arcsec=Z_as, quantiles=False)
    one, two = (_conditioned(geometry, budget, S_um, Z_as, r, workers=w) for w in (1, 2))
    assert all(np.array_equal(a, b) for a, b in zip(one, two))


@pytest.mark.parametrize("pose, Z_as", [([10.0, 120.0, 0.0], 100.0), ([-40.0, 140.0, 0.0], 60.0)])
def test_the_paper_budget_meets_1e_9_where_both_out_is_nearly_closed(pose, Z_as):
    """The paper's budget, U-shape, 100 µm: at benchmarks/bench_yield.py's pose (10, 120, 0) J's bracket closes
    to the target and P(either)'s bound was the channels' sum, 1.45e-9; at (-40, 140, 0) / 60 arcsec J's
    bracket spends its cells at 1.65e-9 wide (its half-width 8.3e-10 leaves 1.7e-10 of room: the channels go to
    target/16). Both now meet the target, inside the Fréchet bracket."""
    r = exact_yield("u-shape", "paper", pose, spec_position_um=100.0, spec_phi_arcsec=Z_as, quantiles=False)
    assert not bool(r.bracketed_any) and float(r.bound_any) <= 1e-9
    lo = max(float(r.exceed_position), float(r.exceed_phi))
    hi = float(r.exceed_position + r.exceed_phi)
    slack = float(r.bound_any + r.bound_position + r.bound_phi)
    assert lo - slack <= float(r.exceed_any) <= hi + slack
