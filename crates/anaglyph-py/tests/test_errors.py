"""Bad input: a clear exception of the right class before any compute."""

from __future__ import annotations

import numpy as np
import pytest

import anaglyph
from anaglyph import _core


def test_every_cause_of_the_core_is_an_exported_class():
    causes = [name for name in vars(_core) if name.endswith("Error")]
    assert len(causes) >= 20
    for name in causes:
        cls = getattr(anaglyph, name)
        assert issubclass(cls, anaglyph.AnaglyphError) and name in anaglyph.__all__
    assert issubclass(anaglyph.ShapeError, ValueError)
    assert issubclass(anaglyph.MissingFileError, FileNotFoundError)
    assert issubclass(anaglyph.TooLargeError, MemoryError)
    assert issubclass(anaglyph.InternalError, RuntimeError)


def test_a_rust_panic_becomes_an_internal_error():
    with pytest.raises(anaglyph.InternalError, match="deliberate panic"):
        _core._panic_for_tests()
    # The package keeps working afterwards.
    assert anaglyph.Rig.preset("paper-2x4").condition_number > 1


def test_captures_are_checked_against_the_rig(tabletop):
    rig, captures, whites = tabletop.rig, dict(tabletop.captures), tabletop.whites
    missing = {k: v for k, v in captures.items() if k != "r1c3"}
    with pytest.raises(anaglyph.CapturesError, match="r1c3"):
        anaglyph.reconstruct(rig, missing, whites=whites, progress=False)
    with pytest.raises(anaglyph.NotFoundError, match="r9c9"):
        anaglyph.reconstruct(rig, {**captures, "r9c9": captures["r0c0"]}, progress=False)
    grey = {**captures, "r0c1": captures["r0c1"][..., 0]}
    with pytest.raises(anaglyph.ShapeError, match="r0c1"):
        anaglyph.reconstruct(rig, grey, whites=whites, progress=False)
    small = {**captures, "r0c2": captures["r0c2"][:-1]}
    with pytest.raises(anaglyph.ShapeError, match="r0c2"):
        anaglyph.reconstruct(rig, small, whites=whites, progress=False)
    signed = {**captures, "r1c0": captures["r1c0"].astype(np.int32)}
    with pytest.raises(TypeError, match="int32"):
        anaglyph.reconstruct(rig, signed, whites=whites, progress=False)
    nan = {**captures, "r1c1": np.where(captures["r1c1"] > 0, captures["r1c1"] / 65535.0, np.nan)}
    with pytest.raises(anaglyph.NonFiniteError, match="r1c1"):
        anaglyph.reconstruct(rig, nan, whites=whites, progress=False)
    with pytest.raises(TypeError, match="numpy array"):
        anaglyph.reconstruct(rig, {**captures, "r0c0": [[1, 2], [3, 4]]}, progress=False)


def test_options_are_checked_before_any_work(tabletop):
    args = (tabletop.rig, tabletop.captures)
    with pytest.raises(anaglyph.DisparityRangeError, match="8:8"):
        anaglyph.reconstruct(*args, whites=tabletop.whites, disp_range=(8, 8), progress=False)
    with pytest.raises(TypeError, match="disp_range"):
        anaglyph.reconstruct(*args, whites=tabletop.whites, disp_range="wide", progress=False)
    with pytest.raises(anaglyph.NotFoundError, match="default, fast, paper"):
        anaglyph.reconstruct(*args, preset="best", progress=False)
    with pytest.raises(anaglyph.NotFoundError, match="cube, registered, both"):
        anaglyph.reconstruct(*args, output="stack", progress=False)
    with pytest.raises(anaglyph.NotFoundError, match="r5c5"):
        anaglyph.reconstruct(*args, views=["r5c5"], progress=False)
    with pytest.raises(anaglyph.OutOfRangeError, match="white reflectance"):
        anaglyph.reconstruct(*args, whites=tabletop.whites, white_reflectance=1.5, progress=False)
    with pytest.raises(anaglyph.ParseError, match="refine_radios"):
        anaglyph.reconstruct(*args, tuning={"refine_radios": 3}, progress=False)
    with pytest.raises(anaglyph.NotFoundError, match="lsqr"):
        anaglyph.reconstruct(*args, solver="qr", progress=False)
    with pytest.raises(TypeError, match="captures"):
        anaglyph.reconstruct(tabletop.rig, list(tabletop.captures.values()), progress=False)


def test_black_captures_are_refused(tabletop):
    black = {k: np.zeros_like(v) for k, v in tabletop.captures.items()}
    with pytest.raises(anaglyph.AnaglyphError, match="r0c0"):
        anaglyph.reconstruct(tabletop.rig, black, whites=tabletop.whites, progress=False)


def test_a_dark_above_its_capture_is_blamed_not_the_capture(tabletop):
    darks = {k: np.zeros_like(v) for k, v in tabletop.captures.items()}
    darks["r0c1"] = np.full_like(tabletop.captures["r0c1"], 60000)
    with pytest.raises(anaglyph.UnusableError, match="camera r0c1 cannot be used: its dark frame "
                       "given in darks is at or above its capture"):
        anaglyph.reconstruct(tabletop.rig, tabletop.captures, whites=tabletop.whites, darks=darks,
                             progress=False)
