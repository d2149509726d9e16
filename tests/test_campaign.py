"""Campaign files (SPEC §4): validation with row/column messages, round trip, and the simulator."""

import warnings

import numpy as np
import pandas as pd
import pytest

from prp3mc import Budget, Geometry, Region
from prp3mc.errors import CampaignError
from prp3mc.measurement.campaign.data import Campaign, count_rows, read_campaign
from prp3mc.measurement.forward.prediction import predict
from prp3mc.measurement.campaign.simulate import SETTLE_S, SLIDER_SPEED_MM_S, simulate_campaign
from prp3mc.measurement.forward.signatures import EFFECT_NAMES, effect, library
from prp3mc.errors import BudgetError, InputFileError, Prp3mcWarning


@pytest.fixture(scope="module")
def setup():
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    poses = Region.from_preset("u-shape").grid(3).reshape(-1, 3)
    return g, b, poses


@pytest.fixture
def frame(setup):
    g, b, poses = setup
    return simulate_campaign(g, b, poses, 2, rng=5).to_frame()


def test_round_trip_csv(setup, tmp_path):
    g, b, poses = setup
    c = simulate_campaign(g, b, poses, 3, rng=1)
    path = tmp_path / "c.csv"
    c.to_csv(path)
    back = read_campaign(path, g)
    assert back.n_measurements == 27 and back.n_poses == 9
    np.testing.assert_allclose(back.measured, c.measured, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.pose_index, c.pose_index)
    assert back.has_dir == (True, True, True) and back.temp_C is not None


def test_any_labels_unequal_repeats_optional_columns(frame, setup):
    g, _, _ = setup
    f = frame.drop(columns=["dir_2", "temp_C", "time_s"]).iloc[:-3].copy()
    f["pose_id"] = f["pose_id"].map(lambda s: f"pose {s.lower()} / A")
    f["operator"] = "kim"                     # other columns are kept and ignored
    c = read_campaign(f, g)
    assert c.has_dir == (True, False, True) and c.temp_C is None
    assert sorted(c.repeats.tolist()) == [1, 1, 1, 2, 2, 2, 2, 2, 2]
    assert list(c.extra.columns) == ["operator"]
    assert {e.name for e in library(None, c.has_dir, False)} >= {"backlash_1", "backlash_3"}
    assert "backlash_2" not in {e.name for e in library(None, c.has_dir, False)}


@pytest.mark.parametrize("edit, expected", [
    (lambda f: f.drop(columns=["y_meas"]), "missing required column(s) y_meas"),
    (lambda f: f.assign(x_meas=f["x_meas"].where(f.index != 4)), "row 5 (line 6), column x_meas: expected a finite number, got empty"),
    (lambda f: f.assign(phi_cmd=f["phi_cmd"].astype(object).where(f.index != 2, "abc")), "row 3 (line 4), column phi_cmd"),
    (lambda f: f.assign(dir_2=np.where(f.index == 6, 0, f["dir_2"])), "row 7 (line 8), column dir_2: an approach direction must be +1 or -1"),
    (lambda f: f.assign(y_meas=np.where(f.index == 1, f["y_meas"] * 1000, f["y_meas"])), "row 2 (line 3), column y_meas"),
    (lambda f: f.assign(pose_id=np.where(f.index == 0, "", f["pose_id"])), "row 1 (line 2), column pose_id"),
    (lambda f: f.assign(temp_C=np.where(f.index == 3, 293.15 + 20, 20.0)), "row 4 (line 5), column temp_C: 313.15 degrees C"),
])
def test_bad_campaigns_name_row_and_column(frame, setup, tmp_path, edit, expected):
    path = tmp_path / "bad.csv"
    edit(frame).to_csv(path, index=False)
    with pytest.raises(CampaignError) as info:
        read_campaign(path, setup[0])
    assert expected in str(info.value)


def test_duplicated_id_with_different_commands(frame, setup):
    f = frame.copy()
    dup = f.index[f["pose_id"] == f.loc[0, "pose_id"]][1]
    f.loc[dup, "x_cmd"] += 0.5
    with pytest.raises(CampaignError, match=rf"rows 1, {dup + 1}, column x_cmd: pose_id '{f.loc[0, 'pose_id']}' "
                                            "is commanded twice with different values"):
        read_campaign(f, setup[0])


def test_pose_out_of_stroke(frame, setup):
    f = frame.copy()
    f.loc[f["pose_id"] == f.loc[3, "pose_id"], ["y_cmd", "y_meas"]] = 400.0
    with pytest.raises(CampaignError, match=r"row 4, column x_cmd, y_cmd, phi_cmd: .*leaves leg"):
        read_campaign(f, setup[0])


def test_unreadable_files(tmp_path):
    with pytest.raises(InputFileError, match="does not exist"):
        read_campaign(tmp_path / "nope.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(InputFileError):
        read_campaign(tmp_path / "empty.csv")
    (tmp_path / "header.csv").write_text("pose_id,x_cmd,y_cmd,phi_cmd,x_meas,y_meas,phi_meas\n")
    with pytest.raises(CampaignError, match="no rows"):
        read_campaign(tmp_path / "header.csv")


def test_effect_names_and_units():
    assert len(EFFECT_NAMES) == 27 + 3 + 3 + 1 + 3 + 9
    assert effect("alpha_2").unit == "deg" and effect("b_1").unit == "mm"
    assert effect("cyclic_2").unit == "mm" and effect("cyclic_2").dof == 2 and effect("cyclic_2").leg == 1
    assert effect("scale_3").unit == "1" and effect("thermal").unit == "1/K"
    assert effect("backlash_1").needs == ("dir_1",) and effect("spread_theta_2").budget_input == "theta_2"
    with pytest.raises(BudgetError, match="unknown effect"):
        effect("rho_1")


def test_simulator_is_reproducible_and_records(setup):
    g, b, poses = setup
    a = simulate_campaign(g, b, poses, 2, effects={"b_1": 0.02}, rng=9)
    c = simulate_campaign(g, b, poses, 2, effects={"b_1": 0.02}, rng=9)
    np.testing.assert_array_equal(a.measured, c.measured)
    assert a.metadata["seed"] == 9 and a.metadata["effects"] == {"b_1": 0.02}
    assert isinstance(simulate_campaign(g, b, poses, 1).metadata["seed"], int)
    with pytest.raises(CampaignError, match="temperature drift"):
        simulate_campaign(g, b, poses, 1, effects={"thermal": 1e-5}, temp_drift_C=None)
    with pytest.raises(BudgetError, match="unknown effect"):
        simulate_campaign(g, b, poses, 1, effects={"lead_1": 1e-4})


@pytest.mark.parametrize("effects", [{}, {"b_1": 0.03, "backlash_2": 0.04, "thermal": 2e-5, "alpha_3": 0.05,
                                          "spread_theta_1": 0.1}, {"scale_2": 2e-4, "beta_1": 0.03}])
def test_simulator_matches_prediction(setup, effects):
    """The exact-model simulator's mean and covariance agree with the linear prediction within 4.5 SE."""
    g, b, _ = setup
    pose = np.array([[10.0, 110.0, 2.0]])
    n = 4000
    c = simulate_campaign(g, b, pose, n, effects=effects, approach="positive", temp_drift_C=(24.0, 24.0),
                          instrument_sigma_mm=0.002, instrument_sigma_deg=0.0005, rng=11)
    pred = predict(g, b, c, effects=effects, instrument_sigma_mm=0.002, instrument_sigma_deg=0.0005)
    err = c.error
    sd = np.sqrt(np.diag(pred.cov[0]))
    np.testing.assert_array_less(np.abs(err.mean(0) - pred.mean[0]), 4.5 * sd / np.sqrt(n))
    var = err.var(0, ddof=1)
    kurt_se = np.sqrt(2.0 / n) * sd**2 * 1.5              # generous for platykurtic sums
    np.testing.assert_array_less(np.abs(var - sd**2), 4.5 * kurt_se)


def test_sequence_and_one_sided_approach(setup):
    g, b, poses = setup
    c = simulate_campaign(g, b, poses, 3, approach="sequence", rng=2)
    assert set(np.unique(c.direction)) <= {-1.0, 1.0}
    assert np.all(simulate_campaign(g, b, poses, 1, approach="negative", rng=2).direction == -1)
    assert isinstance(c, Campaign) and isinstance(c.to_frame(), pd.DataFrame)


# --------------------------------------------------------------------------- the realities of issue 10

SIGMA = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}


@pytest.fixture(scope="module")
def grid49():
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    return g, b, Region.from_preset("u-shape").grid(7).reshape(-1, 3)


def test_realities_off_are_the_plain_campaign(grid49):
    """Zero registration, drift and outliers and r = 0 give the very same numbers as the defaults."""
    g, b, poses = grid49
    plain = simulate_campaign(g, b, poses, 2, effects={"beta_1": 0.02}, rng=6)
    off = simulate_campaign(g, b, poses, 2, effects={"beta_1": 0.02}, registration=(0, 0, 0), drift=(0, 0, 0),
                            outliers=(0.0, 0.5), repeatable_fraction=0.0, rng=6)
    np.testing.assert_array_equal(plain.measured, off.measured)
    assert plain.metadata["registration"] is None and off.metadata["outlier_rows"] == ()


def test_visit_times_are_moves_plus_settling(grid49):
    g, b, poses = grid49
    t = simulate_campaign(g, b, poses, 3, rng=1).to_frame()["time_s"].to_numpy()
    step = np.diff(t)
    assert t[0] == SETTLE_S and (step >= SETTLE_S).all()
    assert (step <= SETTLE_S + 200.0 / SLIDER_SPEED_MM_S).all() and step.std() > 0.5   # realistic, uneven


def _gls(G, r, cov_rows):
    """Generalised least squares of r (M, 3) on G (M, 3, K) with block covariance (M, 3, 3): estimate, SE."""
    W = np.linalg.inv(cov_rows)
    info = np.einsum("mok,mop,mpl->kl", G, W, G)
    est = np.linalg.solve(info, np.einsum("mok,mop,mp->k", G, W, r))
    return est, np.sqrt(np.diag(np.linalg.inv(info)))


def test_registration_and_drift_are_recovered_by_a_rigid_fit(grid49):
    """A rigid transform plus an offset linear in time, fitted to measured minus predicted, recover both within 4.5 SE."""
    g, b, poses = grid49
    reg, drift = (0.060, -0.040, 0.020), (0.050, -0.040, 0.015)
    c = simulate_campaign(g, b, poses, 8, registration=reg, drift=drift, rng=12, **SIGMA)
    pred = predict(g, b, c, **SIGMA)
    t = c.to_frame()["time_s"].to_numpy()
    s = (t - t[0]) / (t[-1] - t[0])
    x, y = c.commanded[:, 0], c.commanded[:, 1]
    rad = np.pi / 180.0
    one, zero = np.ones_like(x), np.zeros_like(x)
    rigid = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, one, zero], -1),
                      np.stack([-y * rad, x * rad, one], -1)], axis=-1)          # (M, 3 rows, 3 params)
    G = np.concatenate([rigid, np.eye(3) * s[:, None, None]], axis=-1)       # registration, then drift
    est, se = _gls(G, c.error - pred.mean, pred.cov[c.pose_index])
    truth = np.array(reg + drift)
    np.testing.assert_array_less(np.abs(est - truth), 4.5 * se)
    assert (4.5 * se < np.abs(truth)).all()                                    # the test can fail
    assert c.metadata["registration"] == reg and c.metadata["drift"] == drift


def test_outliers_have_the_stated_count_and_size(grid49):
    g, b, poses = grid49
    clean = simulate_campaign(g, b, poses, 8, rng=3, **SIGMA)
    dirty = simulate_campaign(g, b, poses, 8, outliers=(0.01, 0.5), rng=3, **SIGMA)
    rows = np.array(dirty.metadata["outlier_rows"])
    assert rows.size == round(0.01 * dirty.n_measurements) == 4
    jump = dirty.measured - clean.measured                                    # the other draws are unchanged
    np.testing.assert_allclose(np.hypot(jump[rows, 0], jump[rows, 1]), 0.5, rtol=1e-12)
    np.testing.assert_array_equal(np.delete(jump, rows, axis=0), 0.0)
    np.testing.assert_array_equal(jump[:, 2], 0.0)


@pytest.mark.parametrize("r", [0.0, 0.6, 1.0])
def test_repeatable_fraction_splits_the_variance(r):
    """Between-pose excess variance over the predicted variance estimates r without bias, within 4.5 SE."""
    g, b = Geometry.from_preset("delta-shape"), Budget.from_preset("paper")
    rng = np.random.default_rng(0)
    poses = np.stack([rng.uniform(-40, 40, 150), rng.uniform(120, 200, 150), rng.uniform(-4, 4, 150)], -1)
    n = 4
    c = simulate_campaign(g, b, poses, n, repeatable_fraction=r, instrument_sigma_mm=0.0,
                          instrument_sigma_deg=0.0, rng=21)
    pred = predict(g, b, c)
    var = np.diagonal(pred.cov, axis1=1, axis2=2)                             # (P, 3)
    resid = c.error - pred.mean
    P = c.n_poses
    mean = np.stack([np.bincount(c.pose_index, resid[:, k], P) for k in range(3)], -1) / n
    within = np.stack([np.bincount(c.pose_index, (resid[:, k] - mean[c.pose_index, k]) ** 2, P)
                       for k in range(3)], -1) / (n - 1)
    t = ((mean**2 - within / n) / var).mean(axis=1)                           # unbiased for r, per pose
    se = t.std(ddof=1) / np.sqrt(P)
    assert abs(t.mean() - r) < 4.5 * se and se < 0.1
    if r == 1.0:                                                              # each pose keeps its errors
        np.testing.assert_allclose(within, 0.0, atol=1e-20)
    assert c.metadata["repeatable_fraction"] == r


@pytest.mark.parametrize("kwargs, message", [
    ({"registration": (0.01, 0.02)}, "registration must be three finite numbers"),
    ({"drift": (0.0, np.nan, 0.0)}, "drift must be three finite numbers"),
    ({"outliers": (1.5, 0.5)}, "outliers: fraction must lie in"),
    ({"outliers": 0.01}, "outliers must be"),
    ({"repeatable_fraction": -0.1}, "repeatable_fraction must lie in"),
    ({"effects": {"backlash_1": 20.0}}, r"effects backlash_1=20: larger than any mm value .* check units"),
    ({"effects": {"cyclic_1": (20.0, 30.0)}}, r"effects cyclic_1=.*larger than any mm value"),
    ({"effects": {"scale_2": 500.0}}, r"effects scale_2=500: larger than any 1 value"),
    ({"instrument_sigma_mm": 2.0}, r"instrument_sigma_mm 2: an instrument noise sd above 0.5 mm; check units"),
    ({"instrument_sigma_deg": 5.0}, r"instrument_sigma_deg 5: an instrument noise sd above 0.5 deg"),
])
def test_bad_reality_settings(setup, kwargs, message):
    g, b, poses = setup
    with pytest.raises(CampaignError, match=message):
        simulate_campaign(g, b, poses, 1, **kwargs)


def test_rows_are_counted_without_reading_the_file(tmp_path):
    """count_rows sizes a campaign before it is parsed: lines after the header, final newline or not."""
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    path = tmp_path / "c.csv"
    simulate_campaign(g, b, Region.from_preset("u-shape").grid(3).reshape(-1, 3), 3, rng=1).to_csv(path)
    assert count_rows(path) == len(read_campaign(path).pose_id) == 27
    path.write_text(path.read_text().rstrip("\n"))
    assert count_rows(path) == 27
    (tmp_path / "h.csv").write_text("pose_id,x_cmd\n")
    (tmp_path / "e.csv").write_text("")
    assert count_rows(tmp_path / "h.csv") == count_rows(tmp_path / "e.csv") == 0
    with pytest.raises(InputFileError, match="does not exist"):
        count_rows(tmp_path / "none.csv")


def test_rows_repeated_with_their_time_are_said(frame, setup, tmp_path):
    """A campaign pasted twice (the same time_s and readings) is read, with a warning naming the rows."""
    path = tmp_path / "twice.csv"
    stamped = frame.assign(time_s=np.arange(len(frame), dtype=float))
    pd.concat([stamped, stamped]).to_csv(path, index=False)
    with pytest.warns(Prp3mcWarning, match=rf"rows {len(frame) + 1}, .*pasted twice"):
        assert len(read_campaign(path, setup[0]).to_frame()) == 2 * len(frame)
    stamped.to_csv(path, index=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", Prp3mcWarning)
        read_campaign(path, setup[0])
