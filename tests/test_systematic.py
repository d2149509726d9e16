"""The [effects] table of a budget: parsing, round trip through TOML, one-line refusals."""

import pytest

from prp3mc import Budget
from prp3mc.errors import BudgetError
from prp3mc.model.effects import SystematicEffect, effects_from_dict

_INPUTS = '[inputs]\nb_1 = {law = "uniform", lo = 0, hi = 0.01}\nb_2 = {law = "uniform", lo = 0, hi = 0.01}\n' \
          'b_3 = {law = "uniform", lo = 0, hi = 0.01}\n'


def test_effects_round_trip_through_toml(tmp_path):
    budget = Budget.from_preset("paper").with_effects({
        "scale_2": SystematicEffect("scale_2", 1.5e-4, ci95=(1.2e-4, 1.8e-4), campaign="c.csv",
                                    campaign_sha256="ab" * 32),
        "backlash_1": SystematicEffect("backlash_1", 0.02),
        "thermal": SystematicEffect("thermal", 1.2e-5, temp_range_C=(15, 25), source="steel"),
        "beta_3": SystematicEffect("beta_3", -0.01),
    })
    path = tmp_path / "budget.toml"
    budget.to_toml(path)
    again = Budget.from_toml(path)
    assert again.effects == budget.effects
    assert again.inputs == budget.inputs
    assert again.effects["thermal"].temp_range_C == (15.0, 25.0)
    assert again.effects["scale_2"].unit == "1"


def test_budget_copies_keep_their_effects():
    budget = Budget.from_preset("paper").with_effects({"b_1": SystematicEffect("b_1", 0.003)})
    assert budget.scaled(2.0).effects == budget.effects
    assert budget.replace(name="x").effects == budget.effects
    assert Budget.from_preset("paper").effects == {}


@pytest.mark.parametrize("table, message", [
    ('[effects.spread_b_1]\nvalue = 0.1', "is a spread"),
    ('[effects.foo_1]\nvalue = 1', "unknown effect 'foo_1'"),
    ('[effects.thermal]\nvalue = 1e-5', "needs temp_range_C"),
    ('[effects.thermal]\nvalue = 1e-5\ntemp_range_C = [30, 10]', "lo <= hi"),
    ('[effects.thermal]\nvalue = 1e-5\ntemp_range_C = [20, 2000]', "outside"),
    ('[effects.scale_1]\nvalue = 0.001\ntemp_range_C = [15, 25]', "thermal only"),
    ('[effects.scale_1]\nvalue = 2.5', "a unit slip"),
    ('[effects.b_1]\nvalue = 2500.0', "a unit slip"),
    ('[effects.scale_1]\nvalue = 0.001\nunit = "mm"', "not the effect's unit"),
    ('[effects.backlash_1]\nvalue = -0.01', "must be >= 0"),
    ('[effects.b_1]\nvalu = 1', "unknown key(s) valu"),
    ('[effects.b_1]\nunit = "mm"', "needs a value"),
    ('[effects]\nb_1 = 0.01', "must be a table"),
    ('[effects.b_1]\nvalue = nan', "finite number"),
    ('[effects.b_1]\nvalue = "0.01"', "finite number"),
    ('[effects.b_1]\nvalue = 0.01\nci95 = [0.02]', "pair"),
    ('[effects.b_1]\nvalue = 0.01\ncampaign = 3', "must be a string"),
    ('effects = 3', "must be a table of effects"),
])
def test_bad_effects_tables_are_refused_in_one_line(tmp_path, table, message):
    path = tmp_path / "budget.toml"
    top_level = not table.startswith("[")            # a top-level key goes before the tables
    path.write_text(table + "\n" + _INPUTS if top_level else _INPUTS + table + "\n")
    with pytest.raises(BudgetError) as info:
        Budget.from_toml(path)
    assert message in str(info.value)
    assert "\n" not in str(info.value)
    assert str(info.value).startswith(str(path))


def test_effects_from_dict_keeps_every_field():
    effects = effects_from_dict({"thermal": {"value": 1.1e-5, "unit": "1/K", "temp_range_C": [10, 30],
                                             "ci95": [1e-5, 1.2e-5], "campaign": "c.csv"}}, "here")
    eff = effects["thermal"]
    assert (eff.value, eff.temp_range_C, eff.ci95, eff.campaign) == (1.1e-5, (10.0, 30.0), (1e-5, 1.2e-5), "c.csv")
    assert eff.effect.kind == "thermal"
