"""Rigs, sensing matrices and filter selection against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

import anaglyph


@pytest.mark.parametrize("name, cameras, channels", [("paper-2x4", 8, 3), ("mono-3x3", 9, 1), ("hexagon-7", 7, 1)])
def test_presets_describe_their_cameras(name, cameras, channels):
    rig = anaglyph.Rig.preset(name)
    assert rig.name == name
    assert len(rig.cameras) == cameras
    assert {c["channels"] for c in rig.cameras} == {channels}
    assert sum(c["reference"] for c in rig.cameras) == 1
    names = [c["name"] for c in rig.cameras]
    assert len(set(names)) == cameras and names[0] in repr(rig)


def test_toml_round_trip_keeps_the_rig():
    rig = anaglyph.Rig.preset("paper-2x4")
    back = anaglyph.Rig.from_toml(rig.to_toml())
    assert back.cameras == rig.cameras
    np.testing.assert_array_equal(back.sensing_matrix()[0], rig.sensing_matrix()[0])
    np.testing.assert_array_equal(back.wavelengths, rig.wavelengths)


def test_the_sensing_matrix_matches_numpy():
    rig = anaglyph.Rig.preset("paper-2x4")
    c, wavelengths = rig.sensing_matrix()
    assert c.shape == (24, wavelengths.size) and c.dtype == np.float64
    assert np.all(np.diff(wavelengths) > 0)
    # The reconstruction bands are a run of the unknowns' wavelengths.
    assert set(rig.wavelengths).issubset(set(wavelengths))
    assert rig.condition_number == pytest.approx(np.linalg.cond(c), rel=1e-6)
    assert len(rig.channel_labels()) == 24


def test_a_rig_file_loads_relative_to_its_folder(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(anaglyph.Rig.preset("mono-3x3").to_toml())
    assert len(anaglyph.Rig.load(path).cameras) == 9
    with pytest.raises(FileNotFoundError):
        anaglyph.Rig.load(tmp_path / "missing.toml")


def test_unknown_keys_and_bad_values_in_a_rig_are_refused():
    text = anaglyph.Rig.preset("paper-2x4").to_toml()
    with pytest.raises(anaglyph.ParseError, match="focal_lenght_px"):
        anaglyph.Rig.from_toml(text.replace("focal_length_px", "focal_lenght_px"))
    with pytest.raises(anaglyph.NotFoundError, match="paper-2x4"):
        anaglyph.Rig.preset("paper-4x2")
    # A layout error is its own cause, and still a ValueError.
    twice = text.replace("row = 0\ncol = 1", "row = 0\ncol = 0", 1)
    assert twice != text
    with pytest.raises(anaglyph.RigLayoutError, match="two cameras at row 0 col 0"):
        anaglyph.Rig.from_toml(twice)
    with pytest.raises(ValueError):
        anaglyph.Rig.from_toml(twice)


def test_filter_selection_ranks_by_the_condition_number():
    best = anaglyph.select_filters(3, keep=3)
    assert len(best) == 3
    conds = [b["condition_number"] for b in best]
    assert conds == sorted(conds)
    assert all(len(b["filters"]) == 3 for b in best)
    with pytest.raises(anaglyph.NotFoundError, match="condition, noise"):
        anaglyph.select_filters(3, criterion="smallest")
    with pytest.raises(anaglyph.OutOfRangeError):
        anaglyph.select_filters(3, lam=-1.0)
