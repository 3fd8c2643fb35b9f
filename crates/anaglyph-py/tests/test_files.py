"""ENVI, PFM and capture files."""

from __future__ import annotations

import numpy as np
import pytest

import anaglyph


def test_envi_round_trip_keeps_values_wavelengths_and_names(tmp_path):
    rng = np.random.default_rng(1)
    cube = rng.random((5, 7, 4), dtype=np.float32)
    cube[0, 0, 0] = np.nan
    path = tmp_path / "cube.hdr"
    anaglyph.write_envi(path, cube, wavelengths=[450, 458, 466, 474], band_names=list("abcd"))
    back, wavelengths, names = anaglyph.read_envi(path)
    assert back.tobytes() == cube.tobytes()
    assert wavelengths == [450, 458, 466, 474] and names == list("abcd")
    header = path.read_text()
    assert "wavelength" in header and "band names" in header


def test_envi_refuses_mismatched_metadata(tmp_path):
    with pytest.raises(anaglyph.RasterError, match="wavelengths"):
        anaglyph.write_envi(tmp_path / "c.hdr", np.zeros((2, 2, 3), np.float32), wavelengths=[1, 2])
    with pytest.raises(anaglyph.RasterError, match="H, W, bands"):
        anaglyph.write_envi(tmp_path / "c.hdr", np.zeros((2, 2), np.float32))
    with pytest.raises(FileNotFoundError):
        anaglyph.read_envi(tmp_path / "absent.hdr")


def test_pfm_round_trip_keeps_infinities(tmp_path):
    plane = np.arange(12, dtype=np.float32).reshape(3, 4)
    plane[1, 2] = np.inf
    anaglyph.write_pfm(tmp_path / "d.pfm", plane)
    assert anaglyph.read_pfm(tmp_path / "d.pfm").tobytes() == plane.tobytes()
    with pytest.raises(TypeError, match="float32"):
        anaglyph.write_pfm(tmp_path / "d.pfm", plane.astype(np.float64))
