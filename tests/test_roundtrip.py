"""Every file prp3mc writes is read back by prp3mc as the same object (issue 25, point 3).

Hypothesis varies names (any Unicode but lone surrogates, control
characters included), units and values. Covered here: geometry.toml and
budget.toml (with [groups], [effects] and fitted_on: the layout of
``DIR/model/`` of a discrepancy run), the campaign CSV a simulated campaign
is written as, and JSON documents (summary.json, discrepancy.json go through
the same writer). The files of whole runs (``DIR/model/*.toml`` of a
discrepancy with odd names, ``prp3mc init`` templates) read back in the
corpus cases of tests/test_bad_input.py (class read-back).
"""

import json
import os

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prp3mc import Budget, Geometry
from prp3mc._toml import dumps_toml, loads_toml
from prp3mc.measurement.campaign.data import Campaign, read_campaign
from prp3mc.model.effects import SystematicEffect
from prp3mc.output import write_json

_EXAMPLES = int(os.environ.get("PRP3MC_FUZZ_EXAMPLES", 25))
_SETTINGS = settings(max_examples=_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
#: The campaign and budget cases validate whole objects (pose feasibility, laws): fewer of them by default.
_FEW = settings(_SETTINGS, max_examples=max(_EXAMPLES // 3, 1))
#: Any text a name can hold in a UTF-8 file: every character but lone surrogates (control characters included).
names = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)
finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@_SETTINGS
@given(names, st.lists(finite, min_size=3, max_size=3), st.lists(st.floats(-360, 360), min_size=3, max_size=3))
def test_geometry_reads_back(tmp_path_factory, name, lengths, angles):
    g = Geometry.from_preset("u-shape").replace(name=name, a=lengths, psi=angles)
    path = tmp_path_factory.mktemp("g") / "geometry.toml"
    g.to_toml(path)
    back = Geometry.from_toml(path)
    assert back == g and back.name == name


_families = st.sampled_from(["theta", "b", "a", "psi", "c"])


@_FEW
@given(name=names, halves=st.dictionaries(_families, st.floats(1e-9, 10.0), min_size=1, max_size=3),
       group_names=st.lists(names.filter(lambda s: s not in ("", ) and not s.startswith("clearance_")),
                            min_size=0, max_size=2, unique=True),
       effect_value=st.floats(-0.5, 0.5), campaign=names, geometry_name=names)
def test_budget_reads_back(tmp_path_factory, name, halves, group_names, effect_value, campaign, geometry_name):
    inputs = {f"{f}_{i}": {"law": "uniform", "lo": -h * i, "hi": h} for f, h in halves.items() for i in (1, 2, 3)}
    members = sorted(inputs)
    groups = {g: members[k:k + 2] for k, g in enumerate(group_names) if g not in inputs}
    groups = {g: m for g, m in groups.items() if len(m) == 2}
    groups = dict(list({tuple(sorted(m)): (g, m) for g, m in groups.items()}.values()))   # distinct member sets
    budget = Budget.from_dict({"name": name, "inputs": inputs, "groups": groups})
    budget = budget.with_effects({"scale_1": SystematicEffect("scale_1", effect_value * 1e-3, campaign=campaign)},
                                 fitted_on=Geometry.from_preset("u-shape").replace(name=geometry_name))
    path = tmp_path_factory.mktemp("b") / "budget.toml"
    budget.to_toml(path)
    back = Budget.from_toml(path)
    assert back.to_dict() == budget.to_dict()
    assert back.name == name and dict(back.groups) == dict(budget.groups)


@_SETTINGS
@given(st.dictionaries(names, st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-2**53, 2**53), finite,
                                                     names),
                                           lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                                   st.dictionaries(names, inner, max_size=3)),
                                           max_leaves=8), max_size=5))
def test_json_reads_back(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("j") / "summary.json"
    write_json(path, doc)
    assert json.loads(path.read_text(encoding="utf-8")) == doc


@_SETTINGS
@given(st.dictionaries(names, st.one_of(finite, names, st.booleans(), st.lists(finite, max_size=3),
                                        st.dictionaries(names, st.one_of(finite, names), max_size=3)), max_size=6))
def test_toml_text_reads_back(doc):
    assert loads_toml(dumps_toml(doc, header="a header\nof two lines")) == doc


#: pose_id labels: any text without surrounding blanks (the reader strips them) and not blank.
labels = st.text(st.characters(blacklist_categories=("Cs", "Zs", "Cc", "Zl", "Zp")), min_size=1, max_size=8) | \
    st.sampled_from(["NA", "none", "null", "nan", "N/A", "-", "P,1", 'P"2', "Gerät", "☃"])


@_FEW
@given(st.lists(labels, min_size=3, max_size=6, unique=True), st.integers(0, 2**32 - 1),
       st.sampled_from(["", "Notiz", "dir_x", "Temperatur °C"]))
def test_campaign_csv_reads_back(tmp_path_factory, ids, seed, extra):
    """A campaign written by Campaign.to_csv (as simulate_campaign's are) reads back to the same campaign."""
    rng = np.random.default_rng(seed)
    n = len(ids)
    cmd = np.column_stack([rng.uniform(-40, 40, n), rng.uniform(60, 140, n), rng.uniform(-5, 5, n)])
    frame = pd.DataFrame({"pose_id": np.repeat(ids, 2)})
    for k, (c, m) in enumerate(zip(("x_cmd", "y_cmd", "phi_cmd"), ("x_meas", "y_meas", "phi_meas"))):
        frame[c] = np.repeat(cmd[:, k], 2)
        frame[m] = frame[c] + rng.normal(0, 0.01, 2 * n)
    frame["dir_1"] = rng.choice([-1, 1], 2 * n)
    frame["temp_C"] = rng.uniform(18, 30, 2 * n)
    frame["time_s"] = rng.permutation(2 * n) * 7.5     # stored in any order
    if extra:
        frame[extra] = rng.normal(size=2 * n)
    g = Geometry.from_preset("u-shape")
    campaign = Campaign.from_frame(frame, g, "c")
    path = tmp_path_factory.mktemp("c") / "campaign.csv"
    campaign.to_csv(path)
    back = read_campaign(path, g)
    assert list(back.pose_id) == list(campaign.pose_id) and back.pose_labels == campaign.pose_labels
    for attr in ("commanded", "measured", "direction", "temp_C"):
        np.testing.assert_array_equal(getattr(back, attr), getattr(campaign, attr), err_msg=attr)
    assert back.has_dir == campaign.has_dir
    pd.testing.assert_frame_equal(back.extra, campaign.extra, check_dtype=False)
