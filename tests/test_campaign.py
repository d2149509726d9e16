"""Campaign files (SPEC §4): validation with row/column messages, round trip, and the simulator."""

import numpy as np
import pandas as pd
import pytest

from prp3mc import Budget, Geometry, Region
from prp3mc.errors import CampaignError
from prp3mc.measurement.campaign import Campaign, read_campaign
from prp3mc.measurement.prediction import predict
from prp3mc.measurement.simulate import simulate_campaign
from prp3mc.measurement.effects import EFFECT_NAMES, effect, library
from prp3mc.errors import BudgetError, InputFileError


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
    f = frame.drop(columns=["dir_2", "temp_C"]).iloc[:-3].copy()
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
    assert len(EFFECT_NAMES) == 27 + 3 + 3 + 1 + 9
    assert effect("alpha_2").unit == "deg" and effect("b_1").unit == "mm"
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
                                          "spread_theta_1": 0.1}])
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
