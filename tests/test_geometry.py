import numpy as np
import pytest

from prp3mc import Geometry, Region
from prp3mc.errors import GeometryError, InputFileError, UnknownPresetError


def test_presets_match_spec_table():
    u = Geometry.from_preset("u-shape")
    assert u.a == (140.0, 140.0, 180.0)
    assert u.alpha == (180.0, 0.0, 90.0)
    assert u.stroke[2] == (-100.0, 100.0)
    d = Geometry.from_preset("delta-shape")
    assert d.beta == (120.0, 60.0, -90.0)
    assert d.psi == (210.0, -30.0, 90.0)
    np.testing.assert_allclose(d.rad("beta"), np.deg2rad([120.0, 60.0, -90.0]))


def test_unknown_preset():
    with pytest.raises(UnknownPresetError, match="unknown geometry preset 'v-shape'"):
        Geometry.from_preset("v-shape")


def test_toml_round_trip(tmp_path, geometry):
    path = tmp_path / "g.toml"
    geometry.to_toml(path)
    assert Geometry.from_toml(path) == geometry
    assert Geometry.load(str(path)) == geometry


def test_immutable(geometry):
    with pytest.raises(AttributeError):
        geometry.a = (1.0, 2.0, 3.0)
    with pytest.raises(ValueError):
        geometry.rad("a")[0] = 5.0


@pytest.mark.parametrize("text, error, message", [
    ("name = 'x'\n[[leg]\n", InputFileError, "malformed TOML"),
    ("name = 'x'\n", GeometryError, "exactly three"),
    ("[[leg]]\na_mm = 1\n[[leg]]\n[[leg]]\n", GeometryError, "leg 1: missing"),
])
def test_bad_toml(tmp_path, text, error, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(error, match=message):
        Geometry.from_toml(path)


def test_wrong_unit_key_is_named(tmp_path, geometry):
    doc = geometry.to_dict()
    doc["leg"][0]["alpha_rad"] = doc["leg"][0].pop("alpha_deg")
    with pytest.raises(GeometryError, match="alpha_rad.*degrees"):
        Geometry.from_dict(doc)


def test_missing_file():
    with pytest.raises(InputFileError, match="no such file"):
        Geometry.from_toml("does/not/exist.toml")


@pytest.mark.parametrize("change, message", [
    ({"a": (1.0, np.nan, 2.0)}, "finite"),
    ({"stroke": ((0, 200), (200, 0), (0, 1))}, "stroke of leg 2"),
    ({"c": (1.0, 2.0)}, "three values"),
])
def test_invalid_values(geometry, change, message):
    with pytest.raises(GeometryError, match=message):
        geometry.replace(**change)


def test_region_grid():
    grid = Region.from_preset("u-shape").grid((5, 3))
    assert grid.shape == (3, 5, 3)
    assert grid[0, 0].tolist() == [-40.0, 60.0, 0.0]
    assert grid[-1, -1].tolist() == [40.0, 140.0, 0.0]
