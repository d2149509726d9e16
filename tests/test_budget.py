import numpy as np
import pytest
from scipy import stats

from prp3mc import Budget, Catalogue, Disc, Discrete, Normal, Triangular, TruncNormal, Uniform
from prp3mc.errors import BudgetError, IncompleteBudgetWarning, InputFileError, UnknownPresetError
from prp3mc.model.laws import law_from_dict

LAWS = [Uniform(-1.0, 3.0), Normal(0.5, 0.2), TruncNormal(0.0, 0.01, 1.33), Triangular(0.0, 0.2, 1.0),
        Disc(0.016), Discrete((0.0, 0.005, 0.01), (0.2, 0.5, 0.3))]


@pytest.mark.parametrize("law", LAWS, ids=lambda law: law.kind)
def test_law_moments_match_samples(law, seed):
    """ppf sampling reproduces each law's closed-form mean and variance (5 SE)."""
    n = 200_000
    x = law.ppf(np.random.default_rng(seed).random(n))
    sd = np.sqrt(law.var)
    assert abs(x.mean() - law.mean) < 5 * sd / np.sqrt(n) + 1e-15
    kurt = stats.kurtosis(x, fisher=False)
    assert abs(x.var() - law.var) < 5 * law.var * np.sqrt((kurt - 1) / n) + 1e-18
    lo, hi = law.support
    assert x.min() >= lo and x.max() <= hi


def test_truncnormal_from_tolerance_and_cpk():
    law = TruncNormal(center=1.0, tol=0.03, cpk=1.0)
    assert law.support == (0.97, 1.03)
    ref = stats.truncnorm(-3, 3, loc=1.0, scale=0.01)
    assert law.var == pytest.approx(ref.var(), rel=1e-12)
    np.testing.assert_allclose(law.ppf(np.array([0.1, 0.5, 0.9])), ref.ppf([0.1, 0.5, 0.9]), rtol=1e-12)


def test_paper_preset():
    b = Budget.from_preset("paper")
    assert len(b) == 12
    assert set(b.groups) == {"clearance_1", "clearance_2", "clearance_3"}
    assert b.inputs["rho_2"] == Uniform(0.0, 0.016)
    assert b.inputs["theta_3"] == Uniform(-0.04, 0.04)
    assert b.inputs["b_1"] == Uniform(0.0, 0.025)
    assert b.inputs["zeta_1"] == Uniform(0.0, 360.0)
    assert "source paper" in b.sources["rho_1"]
    np.testing.assert_array_equal(b.bounds()[3], [0.0, 0.025])


def test_same_seed_same_samples():
    b = Budget.from_preset("paper")
    np.testing.assert_array_equal(b.sample(100_000, 5), b.sample(100_000, 5))
    assert not np.array_equal(b.sample(10, 5), b.sample(10, 6))


def test_toml_round_trip(tmp_path):
    b = Budget.from_preset("paper").replace(theta_1=Triangular(-0.02, 0.0, 0.05), rho_3=Disc(0.01))
    b = Budget(b.inputs, groups={"leg_1": ("rho_1", "zeta_1", "theta_1", "b_1")}, sources=b.sources, name="mine")
    path = tmp_path / "b.toml"
    b.to_toml(path)
    again = Budget.from_toml(path)
    assert again.inputs == b.inputs
    assert again.groups == b.groups
    assert Budget.load(str(path)).name == "mine"


def test_catalogue_entries_state_sources():
    cat = Catalogue.bundled()
    frame = cat.to_frame()
    assert frame["source"].str.len().min() > 10
    law, meta = cat.law("bearing_radial_clearance.bore_10_18.C3", "test")
    assert law == Uniform(0.0, 0.0125) and meta["applies_to"] == "rho"


def test_user_catalogue(tmp_path):
    (tmp_path / "parts.toml").write_text(
        '[guide.mine]\nlaw = "uniform"\nlo = -0.01\nhi = 0.01\napplies_to = "theta"\nsource = "our test rig"\n')
    (tmp_path / "b.toml").write_text(
        'catalogues = ["parts.toml"]\n[inputs]\n'
        + "".join(f'theta_{i} = {{ catalogue = "guide.mine" }}\n' for i in (1, 2, 3)))
    b = Budget.from_toml(tmp_path / "b.toml")
    assert b.inputs["theta_1"] == Uniform(-0.01, 0.01)
    assert b.sources["theta_1"] == "guide.mine: our test rig"


@pytest.mark.parametrize("inputs, message", [
    ({"rho_4": {"law": "uniform", "lo": 0, "hi": 1}}, "unknown input 'rho_4'"),
    ({"wobble_1": {"law": "uniform", "lo": 0, "hi": 1}}, "unknown input 'wobble_1'"),
    ({"b_1": {"law": "uniform", "lo": 1, "hi": 0}}, "input 'b_1': uniform law: lo = 1"),
    ({"b_1": {"law": "normal", "mu": 0, "sd": -1}}, "sd = -1"),
    ({"b_1": {"law": "gamma", "k": 1}}, "unknown law 'gamma'"),
    ({"b_1": {"law": "uniform", "lo": 0}}, "missing hi"),
    ({"b_1": {"law": "uniform", "lo": 0, "hi": 1, "mode": 2}}, "unknown mode"),
    ({"b_1": {"law": "triangular", "lo": 0, "mode": 2, "hi": 1}}, "lo <= mode <= hi"),
    ({"b_1": {"law": "discrete", "values": [1, 2], "weights": [1]}}, "equal length"),
    ({"b_1": {"law": "uniform", "lo": "a", "hi": 1}}, "finite number"),
    ({"rho_1": {"law": "uniform", "lo": 0, "hi": 0.01}}, "rho_1' needs zeta_1"),
    ({"rho_1": {"law": "uniform", "lo": -0.01, "hi": 0.01}, "zeta_1": {"law": "uniform", "lo": 0, "hi": 360}},
     "cannot be negative"),
    ({"theta_1": {"catalogue": "encoder_least_count.paper"}}, "applies to b, not theta"),
    ({"theta_1": {"catalogue": "no.such.entry"}}, "no catalogue entry"),
])
def test_bad_budgets_are_refused(inputs, message):
    with pytest.raises(BudgetError, match=message):
        Budget.from_dict({"inputs": inputs})


def test_bad_budget_files(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[inputs\n")
    with pytest.raises(InputFileError, match="malformed TOML"):
        Budget.from_toml(path)
    path.write_text('name = "x"\n')
    with pytest.raises(BudgetError, match=r"needs an \[inputs\] table"):
        Budget.from_toml(path)
    with pytest.raises(UnknownPresetError, match="unknown budget preset 'papr'"):
        Budget.load("papr")


def test_group_validation():
    b = Budget.from_preset("paper")
    with pytest.raises(BudgetError, match="group 'g': unknown input"):
        Budget(b.inputs, groups={"g": ("theta_1", "theta_9")})


def test_unbounded_law_needs_k_sigma():
    b = Budget.from_preset("paper").replace(theta_1=Normal(0.0, 0.01))
    with pytest.raises(BudgetError, match="theta_1.*k_sigma"):
        b.bounds()
    np.testing.assert_allclose(b.bounds(3.0)[2], [-0.03, 0.03])


def test_scaled():
    b = Budget.from_preset("paper").scaled(1.1, "theta")
    assert b.inputs["theta_2"].support == pytest.approx((-0.044, 0.044), rel=1e-12)
    assert b.inputs["b_2"] == Uniform(0.0, 0.025)
    assert law_from_dict({"law": "disc", "radius": 1.0}, "x") == Disc(1.0)


def test_law_scaled():
    assert Triangular(-1.0, 0.0, 2.0).scaled(0.5) == Triangular(-0.5, 0.0, 1.0)
    assert Discrete((0.0, 2.0), (1.0, 3.0)).scaled(2.0) == Discrete((0.0, 4.0), (0.25, 0.75))
    with pytest.raises(BudgetError, match="factor >= 0"):
        Uniform(0.0, 1.0).scaled(-1.0)


def test_missing_legs_warn_and_are_named(tmp_path):
    """A budget cut at a table boundary runs, but says which inputs it lacks (and records them)."""
    full = Budget.from_preset("paper").to_dict()
    path = tmp_path / "cut.toml"
    Budget.from_preset("paper").to_toml(path)
    text = path.read_text()
    path.write_text(text[:text.index("[inputs.theta_3]")])  # the file ends before leg 3's theta and b
    with pytest.warns(IncompleteBudgetWarning, match=r"no law for b_3, theta_3 \(other legs have one\)"):
        b = Budget.from_toml(path)
    assert b.missing_inputs == ("b_3", "theta_3")
    assert Budget.from_dict(full).missing_inputs == ()  # the paper budget is complete: no warning


@pytest.mark.parametrize("doc, message", [
    ({"name": {"a": 1}, "inputs": {"b_1": {"law": "uniform", "lo": 0, "hi": 1}}}, "name must be a string"),
    ({"inputs": {"b_1": {"a": 1}}}, r"\{a = 1\} is not a law"),
    ({"inputs": {"b_1": 0.01}}, "0.01 is not a law"),
    ({"inputs": {"b_1": {"law": "uniform", "lo": 0, "hi": 1e308}}}, r"beyond any error.*±1000 mm"),
    ({"inputs": {"theta_1": {"law": "normal", "mu": 0, "sd": 1e200}}}, r"beyond any error.*±720 deg"),
    ({"inputs": {"theta_1": {"law": "normal", "mu": 0, "sd": 200}}}, r"beyond any error"),
    ({"inputs": {"b_1": {"law": "discrete", "values": [0, 1e300], "weights": [1, 1]}}}, "beyond any error"),
    ({"inputs": {"b_1": {"law": "truncnormal", "center": 0, "tol": 0.01, "cpk": 1e-300}}}, "cpk >= 0.01"),
])
def test_values_that_are_not_laws_or_overflow_are_refused(doc, message):
    with pytest.raises(BudgetError, match=message):
        Budget.from_dict(doc)


def test_k_sigma_is_bounded():
    b = Budget.from_preset("paper").replace(theta_1=Normal(0.0, 0.01))
    for k in (0.0, -1.0, 1e300, float("nan")):
        with pytest.raises(BudgetError, match="k_sigma must lie in"):
            b.bounds(k)


def test_a_discrete_law_of_words_is_refused_in_one_line():
    with pytest.raises(BudgetError, match="discrete law: values and weights must be numbers"):
        Discrete(values=["a", 0.01], weights=[0.5, 0.5])
    with pytest.raises(BudgetError, match="must be numbers"):
        Budget.from_dict({"inputs": {"b_3": {"law": "discrete", "values": ["a", 0.01], "weights": [0.5, 0.5]}}})


def test_the_disc_law_is_for_clearances_only():
    with pytest.raises(BudgetError, match="rho_i only"):
        Budget({"b_3": Disc(0.01)})
    assert Budget({"rho_1": Disc(0.01), "zeta_1": Uniform(0.0, 360.0)}).inputs["rho_1"] == Disc(0.01)
