"""ISO 9283 pose accuracy and repeatability: hand-computed figures, and measured = predicted when the model is right."""

import numpy as np
import pandas as pd
import pytest

from prp3mc import Budget, Geometry, Region
from prp3mc.errors import CampaignError
from prp3mc.measurement.campaign.data import read_campaign
from prp3mc.measurement.campaign.iso9283 import iso9283_figures, pose_means
from prp3mc.measurement.forward.prediction import noise_cov, predict
from prp3mc.measurement.campaign.simulate import simulate_campaign


def tiny():
    """Pose A visited 3 times, pose B twice, pose C once; errors chosen to be computed by hand."""
    err = np.array([[0.01, 0.0, 0.001], [0.03, 0.0, 0.002], [0.02, 0.03, 0.003],       # A at (0, 100, 0)
                    [0.0, 0.004, -0.01], [0.0, -0.004, -0.02],                         # B at (10, 100, 2)
                    [0.5, 0.5, 0.5]])                                                  # C at (-10, 90, 0)
    cmd = np.array([[0, 100, 0]] * 3 + [[10, 100, 2]] * 2 + [[-10, 90, 0]], dtype=float)
    frame = pd.DataFrame({"pose_id": ["A", "A", "A", "B", "B", "C"],
                          **{c: cmd[:, k] for k, c in enumerate(("x_cmd", "y_cmd", "phi_cmd"))},
                          **{c: cmd[:, k] + err[:, k] for k, c in enumerate(("x_meas", "y_meas", "phi_meas"))}})
    return read_campaign(frame)


def test_hand_computed_figures():
    c = tiny()
    zero = np.zeros((3, 3, 3))
    mean = np.array([[0.003, 0.004, -0.001], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    out = iso9283_figures(c, mean, zero, rng=1)
    f = out["per_pose"].set_index(["pose_id", "statistic"])
    l_a = np.array([np.sqrt(2) * 0.01, np.sqrt(2) * 0.01, 0.02])          # distances from the barycentre (0.02, 0.01)
    expected = {("A", "AP"): np.hypot(0.02, 0.01), ("A", "RP"): l_a.mean() + 3 * l_a.std(ddof=1),
                ("A", "AP_phi"): 0.002, ("A", "RP_phi"): 3 * 0.001,
                ("B", "AP"): 0.0, ("B", "RP"): 0.004, ("B", "AP_phi"): 0.015, ("B", "RP_phi"): 3 * 0.01 / np.sqrt(2),
                ("C", "AP"): np.hypot(0.5, 0.5), ("C", "AP_phi"): 0.5}
    for key, value in expected.items():
        assert f.loc[key, "measured"] == pytest.approx(value, rel=1e-9, abs=1e-15), key
    assert np.isnan(f.loc[("C", "RP"), "measured"]) and np.isnan(f.loc[("C", "RP_phi"), "measured"])
    assert out["measured"] == pytest.approx({"AP_mm": np.hypot(0.5, 0.5), "RP_mm": expected[("A", "RP")],
                                             "AP_phi_deg": 0.5, "RP_phi_deg": 3 * 0.01 / np.sqrt(2)})
    # a model without scatter predicts its mean exactly and no repeatability error
    assert f.loc[("A", "AP"), "predicted"] == pytest.approx(0.005, rel=1e-12)
    assert f.loc[("A", "AP_phi"), "predicted"] == pytest.approx(0.001, rel=1e-12)
    assert f.loc[("A", "RP"), "predicted"] == pytest.approx(0.0, abs=1e-15)
    assert f.loc[("A", "RP_phi"), "predicted"] == pytest.approx(0.0, abs=1e-15)
    assert set(out["per_pose"]["unit"]) == {"mm", "deg"} and out["seed"] == 1
    assert list(out["per_pose"].columns) == ["pose_id", "x_mm", "y_mm", "phi_deg", "n", "statistic", "measured",
                                             "predicted", "predicted_sd", "unit"]
    # rows set aside leave the figures of the others
    keep = np.array([True, True, True, True, True, False])
    assert iso9283_figures(c, mean, zero, keep=keep, rng=1)["measured"]["AP_mm"] == pytest.approx(np.hypot(0.02, 0.01))


def test_isotropic_scatter_against_its_closed_form():
    """n visits of N(0, s^2 I2): E[RP_phi] = 3 s c4(n) and E[AP] = s sqrt(pi / (2 n)) (Rayleigh), within MC error."""
    from scipy.special import gammaln
    c = tiny()
    s, n_mc = 0.01, 20000
    cov = np.broadcast_to(np.diag([s**2, s**2, s**2]), (3, 3, 3))
    f = iso9283_figures(c, np.zeros((3, 3)), cov, n_mc=n_mc, rng=5)["per_pose"].set_index(["pose_id", "statistic"])
    n = 3
    c4 = np.sqrt(2 / (n - 1)) * np.exp(gammaln(n / 2) - gammaln((n - 1) / 2))
    for key, value in {("A", "RP_phi"): 3 * s * c4, ("A", "AP"): s * np.sqrt(np.pi / (2 * n))}.items():
        row = f.loc[key]
        assert abs(row["predicted"] - value) < 4.5 * row["predicted_sd"] / np.sqrt(n_mc), key


@pytest.mark.parametrize("r", [0.0, 0.7])
def test_measured_matches_predicted_on_a_simulated_campaign(r):
    """Summed over 49 poses, measured minus predicted figures stay within 4.5 of their standard errors."""
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    poses = Region.from_preset("u-shape").grid(7).reshape(-1, 3)
    poses[:, 2] = np.tile([-4.0, 0.0, 4.0], 17)[:49]
    sigma = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}
    c = simulate_campaign(g, b, poses, 8, repeatable_fraction=r, rng=17, **sigma)
    pred = predict(g, b, c, **sigma)
    noise = noise_cov(0.002, 0.0005)
    budget_cov = pred.cov - noise
    out = iso9283_figures(c, pose_means(pred.mean, c.pose_index, c.n_poses), (1 - r) * budget_cov + noise,
                          predicted_repeat_cov=r * budget_cov, n_mc=2000, rng=2)
    per = out["per_pose"]
    for stat, rows in per.groupby("statistic"):
        diff = (rows["measured"] - rows["predicted"]).sum()
        se = np.sqrt((rows["predicted_sd"] ** 2).sum())
        assert abs(diff) < 4.5 * se, (stat, diff / se)
    # the largest over the 49 poses, like for like: within its spread between campaigns
    for key, measured in out["measured"].items():
        assert abs(measured - out["predicted"][key]) < 4.5 * out["predicted_sd"][key], key
    # the figures are of the right size: RP of micrometres, AP of the budget's mean error
    assert 0.01 < out["measured"]["RP_mm"] < 1.0 and out["predicted"]["AP_mm"] > 0


def test_bad_shapes():
    c = tiny()
    with pytest.raises(CampaignError, match=r"predicted_mean must have shape \(3, 3\)"):
        iso9283_figures(c, np.zeros((2, 3)), np.zeros((3, 3, 3)))
    with pytest.raises(CampaignError, match="keep must have one flag"):
        iso9283_figures(c, np.zeros((3, 3)), np.zeros((3, 3, 3)), keep=[True])


def test_report_removes_nuisances_sets_outliers_aside_and_shows_them(tmp_path):
    """The analysis's ISO figures are those of the campaign without registration and gross errors; the report shows them."""
    import json

    from prp3mc.measurement.discrepancy.workflow import discrepancy
    from prp3mc.reports.discrepancy_report import write_report
    g, b = Geometry.from_preset("u-shape"), Budget.from_preset("paper")
    poses = Region.from_preset("u-shape").grid(5).reshape(-1, 3)
    sigma = {"instrument_sigma_mm": 0.002, "instrument_sigma_deg": 0.0005}
    reg = (0.05, -0.03, 0.01)
    clean = simulate_campaign(g, b, poses, 4, rng=8, **sigma)
    dirty = simulate_campaign(g, b, poses, 4, registration=reg, outliers=(0.05, 0.5), rng=8, **sigma)
    rows = list(dirty.metadata["outlier_rows"])
    result = discrepancy(g, b, dirty, n_bootstrap=50, rng=1, **sigma)
    assert [o["row"] for o in result.outliers] == rows
    keep = np.ones(clean.n_measurements, bool)
    keep[rows] = False
    expected = iso9283_figures(clean, np.zeros((clean.n_poses, 3)), np.zeros((clean.n_poses, 3, 3)), keep=keep)
    # the fitted registration and drift are removed, each known to a few of its standard errors
    fitted = {n["name"]: n for n in result.nuisance}
    error = sum(abs(fitted[f"registration_{k}"]["value"] - v) for k, v in zip("xy", reg[:2]))
    error += abs(fitted["registration_phi"]["value"] - reg[2]) * np.pi / 180 * np.abs(poses[:, :2]).max()
    error += np.hypot(*[result.drift_test["values"][f"drift_{k}"] for k in "xy"])
    measured = result.iso9283_poses.set_index(["pose_id", "statistic"])["measured"]
    truth = expected["per_pose"].set_index(["pose_id", "statistic"])["measured"]
    position = truth.index.get_level_values("statistic").isin(["AP", "RP"])
    np.testing.assert_allclose(measured[truth.index][position], truth[position], atol=2 * error + 1e-6)
    write_report(result, tmp_path / "rep")
    html = (tmp_path / "rep" / "report.html").read_text()
    for text in ("registration_phi", "Gross errors set aside", f"<td>{rows[0]}</td>", "With them kept",
                 "ISO 9283", "iso9283", f"{result.iso9283['measured']['RP_mm'] * 1000:.3g}"):
        assert text in html, text
    doc = json.loads((tmp_path / "rep" / "discrepancy.json").read_text())
    assert set(doc["iso9283"]) == {"measured", "predicted"}
    assert set(doc["iso9283"]["measured"]) == {"AP_mm", "RP_mm", "AP_phi_deg", "RP_phi_deg"}
