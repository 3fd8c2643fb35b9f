"""`demux`: Eq. 6 per pixel, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

import anaglyph


@pytest.fixture(scope="module")
def sensing():
    return anaglyph.Rig.preset("paper-2x4").sensing_matrix()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_a_flat_grey_is_recovered_for_any_leading_shape(sensing, dtype):
    c, wavelengths = sensing
    s = np.full(wavelengths.size, 0.5)
    p = np.broadcast_to(c @ s, (2, 3, 5, c.shape[0])).astype(dtype)
    out = anaglyph.demux(p, c)
    assert out.shape == (2, 3, 5, wavelengths.size) and out.dtype == dtype
    np.testing.assert_allclose(out, 0.5, atol=2e-3)


def test_non_contiguous_and_read_only_inputs_are_read_as_they_are(sensing):
    c, wavelengths = sensing
    p = np.tile(c @ np.full(wavelengths.size, 0.25), (4, 2, 1)).astype(np.float32)
    strided = p[::2]
    readonly = p.copy()
    readonly.setflags(write=False)
    np.testing.assert_array_equal(anaglyph.demux(strided, c), anaglyph.demux(p, c)[::2])
    np.testing.assert_array_equal(anaglyph.demux(readonly, c), anaglyph.demux(p, c))


def test_a_mask_leaves_out_measurements(sensing):
    c, wavelengths = sensing
    p = np.tile(c @ np.full(wavelengths.size, 0.5), (3, 1))
    mask = np.ones(p.shape, dtype=bool)
    mask[1, :3] = False  # one camera's three channels unseen at pixel 1
    mask[2, :] = False  # nothing seen at pixel 2
    out = anaglyph.demux(p, c, mask=mask)
    np.testing.assert_allclose(out[:2], 0.5, atol=5e-3)
    assert np.all(np.isnan(out[2]))


def test_shapes_and_dtypes_are_checked_before_solving(sensing):
    c, _ = sensing
    with pytest.raises(anaglyph.ShapeError, match="24"):
        anaglyph.demux(np.zeros((4, 23), np.float32), c)
    with pytest.raises(TypeError, match="float32 or float64"):
        anaglyph.demux(np.zeros((4, 24), np.int32), c)
    with pytest.raises(anaglyph.NotFoundError, match="exact"):
        anaglyph.demux(np.zeros((4, 24)), c, solver="fastest")
