"""`match`: a rectified pair with a known shift."""

from __future__ import annotations

import numpy as np
import pytest

import anaglyph

SHIFT = 6


def textured_pair(contrast: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A random texture smoothed to a few pixels, and the same texture moved SHIFT px
    left (x_right = x_left - SHIFT), both in [0, 1]."""
    rng = np.random.default_rng(7)
    noise = rng.random((96, 160 + SHIFT))
    kernel = np.ones(3) / 3
    smooth = np.apply_along_axis(lambda r: np.convolve(r, kernel, "same"), 1, noise)
    smooth = np.apply_along_axis(lambda c: np.convolve(c, kernel, "same"), 0, smooth)
    left = smooth[:, :160]
    right = smooth[:, SHIFT : 160 + SHIFT]
    if contrast < 0:
        right = 1.0 - right
    return left.astype(np.float32), right.astype(np.float32)


@pytest.mark.parametrize("method", ["census", "mccnn", "mccnn-lean"])
def test_a_shifted_texture_gives_its_shift(method):
    left, right = textured_pair()
    d, info = anaglyph.match(left, right, disp_range=(0, 16), method=method, return_info=True)
    assert d.shape == left.shape and d.dtype == np.float32
    assert not np.isinf(d).any()
    inner = d[8:-8, 24:-8]
    assert np.mean(np.abs(inner - SHIFT) < 1.0) > 0.95
    assert info["method"] == method and "cost" in info["timings_s"]


def test_an_inverted_pair_is_found_by_the_contrast_vote():
    left, right = textured_pair(contrast=-1.0)
    d, info = anaglyph.match(left, right, disp_range=16, method="census", return_info=True)
    assert info["contrast"]["inverted"] is True
    assert np.mean(np.abs(d[8:-8, 24:-8] - SHIFT) < 1.0) > 0.95


def test_uint8_and_uint16_pairs_give_the_float_pair_s_map():
    left, right = textured_pair()
    as_u16 = [np.round(a * 65535).astype(np.uint16) for a in (left, right)]
    d16 = anaglyph.match(*as_u16, disp_range=(0, 16), method="census")
    dfloat = anaglyph.match(*(a / 65535.0 for a in as_u16), disp_range=(0, 16), method="census")
    np.testing.assert_array_equal(d16, dfloat)


def test_any_memory_layout_gives_the_c_ordered_pair_s_map():
    left, right = textured_pair()
    expected = anaglyph.match(left, right, disp_range=(0, 16), method="census")
    fortran = [np.asfortranarray(a) for a in (left, right)]
    strided = [np.repeat(a, 2, axis=1)[:, ::2] for a in (left, right)]
    for pair in (fortran, strided):
        np.testing.assert_array_equal(anaglyph.match(*pair, disp_range=(0, 16), method="census"), expected)


def test_bad_ranges_and_pairs_are_refused():
    left, right = textured_pair()
    with pytest.raises(ValueError, match="4:4"):
        anaglyph.match(left, right, disp_range=(4, 4))
    with pytest.raises(ValueError, match="width"):
        anaglyph.match(left, right, disp_range=(0, 400))
    with pytest.raises(ValueError):
        anaglyph.match(left, right[:, :-1], disp_range=(0, 16))
    with pytest.raises(TypeError, match="uint8, uint16, float32 or float64"):
        anaglyph.match(left.astype(np.int64), right, disp_range=(0, 16))
    with pytest.raises(anaglyph.NotFoundError, match="census"):
        anaglyph.match(left, right, disp_range=(0, 16), method="sad")
    with pytest.raises(anaglyph.UnusableError, match="model"):
        anaglyph.match(left, right, disp_range=(0, 16), method="mccnn-accurate")


def test_a_pair_too_large_for_memory_is_refused_before_allocating(monkeypatch):
    left, right = textured_pair()
    monkeypatch.setenv("ANAGLYPH_MAX_MEMORY", "100000")
    with pytest.raises(MemoryError, match="a smaller range or image needs less"):
        anaglyph.match(left, right, disp_range=(0, 16))
    with pytest.raises(anaglyph.TooLargeError):
        anaglyph.match(left, right, disp_range=(0, 16), method="census")


def test_a_pair_without_signal_is_refused():
    left, right = textured_pair()
    with pytest.raises(anaglyph.UnusableError, match="left image cannot be used: its capture is black"):
        anaglyph.match(np.zeros_like(left), right, disp_range=(0, 16))
    with pytest.raises(anaglyph.UnusableError, match="constant"):
        anaglyph.match(left, np.full_like(right, 0.5), disp_range=(0, 16))
