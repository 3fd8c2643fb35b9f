"""`calibrate`: homographies onto the reference camera through a checkerboard's plane,
against the plane's closed form and the CLI's files."""

from __future__ import annotations

import json

import numpy as np
import pytest

import anaglyph

from conftest import run_cli

#: A 9x6 checkerboard (10 x 7 squares of 40 mm) 1661.5 mm in front of the array.
BOARD_SCENE = """
name = "checkerboard"
[[object]]
rectangle = { centre_mm = [45, 25, 1700], size_mm = [3000, 3000] }
material = { srgb = [0.85, 0.85, 0.85] }
[[object]]
rectangle = { centre_mm = [45, 25, 1661.5], size_mm = [400, 280] }
material = { pattern = "checker", period_mm = 40, srgb = [0.05, 0.05, 0.05], srgb2 = [0.9, 0.9, 0.9] }
"""
FOCAL_PX, PLANE_MM = 720.0, 1661.5


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    folder = tmp_path_factory.mktemp("board")
    (folder / "board.toml").write_text(BOARD_SCENE)
    text = anaglyph.Rig.preset("paper-2x4").to_toml().replace("focal_length_px = 1800.0", f"focal_length_px = {FOCAL_PX}")
    (folder / "rig.toml").write_text(text)
    rig = anaglyph.Rig.load(folder / "rig.toml")
    sim = anaglyph.simulate(str(folder / "board.toml"), rig=rig, size=(256, 192))
    return folder, rig, sim


def test_homographies_shift_by_the_plane_s_disparity(board):
    _, rig, sim = board
    fits = anaglyph.calibrate(sim.captures, rig, pattern=(9, 6))
    assert set(fits) == {c["name"] for c in rig.cameras}
    np.testing.assert_allclose(fits["r0c0"]["homography"], np.eye(3), atol=1e-9)
    # A plane at Z shifts each camera by f B / Z: 13.0 px per 30 mm column, 21.7 px per
    # 50 mm row.
    column, row = FOCAL_PX * 30 / PLANE_MM, FOCAL_PX * 50 / PLANE_MM
    for name, (dx, dy) in {"r0c1": (column, 0), "r0c3": (3 * column, 0), "r1c0": (0, row)}.items():
        h = fits[name]["homography"]
        assert abs(abs(h[0, 2]) - dx) < 0.5 and abs(abs(h[1, 2]) - dy) < 0.5, (name, h)
        assert fits[name]["residual_rms_px"] < 0.3
        assert fits[name]["corners"].shape == (54, 2)


def test_the_homographies_are_the_cli_s(cli, board, tmp_path):
    folder, rig, sim = board
    run_cli(cli, "simulate", "--scene", str(folder / "board.toml"), "--rig", str(folder / "rig.toml"),
            "--size", "256x192", "--out", str(tmp_path / "sim"))
    run_cli(cli, "calibrate", "--checkerboard", "9x6", "--rig", str(folder / "rig.toml"),
            "--images", str(tmp_path / "sim" / "captures"), "--out", str(tmp_path / "calib"))
    fits = anaglyph.calibrate(sim.captures, rig, pattern=(9, 6))
    for name, fit in fits.items():
        stored = json.loads((tmp_path / "calib" / f"{name}.json").read_text())
        h = np.array(stored["homography"]["data"]).reshape(3, 3)
        np.testing.assert_allclose(fit["homography"], h, rtol=1e-12, atol=1e-12)


def test_a_capture_without_a_board_is_refused_naming_the_camera(board, tabletop):
    _, rig, _ = board
    with pytest.raises(anaglyph.AnaglyphError, match="r0c0"):
        anaglyph.calibrate(tabletop.captures, rig, pattern=(9, 6))
    with pytest.raises(ValueError, match="pattern"):
        anaglyph.calibrate(tabletop.captures, rig, pattern=(1, 6))


def test_every_camera_without_the_board_is_named_with_what_it_saw(board):
    _, rig, sim = board
    with pytest.raises(anaglyph.UnusableError, match=r"no 8x6 checkerboard found in their calibration captures "
                       r"\(each: a whole 9x6 grid of inner corners\); is the board 9x6\?"):
        anaglyph.calibrate(sim.captures, rig, pattern=(8, 6))
    boards = dict(sim.captures)
    for name in ["r0c1", "r1c2"]:
        boards[name] = np.full_like(boards[name], 30000)
    with pytest.raises(anaglyph.UnusableError, match=r"cameras r0c1, r1c2 cannot be used: .*\(each: 0 inner "
                       r"corners labelled\); every inner corner must be in the picture"):
        anaglyph.calibrate(boards, rig, pattern=(9, 6))


def test_a_camera_mounted_upside_down_is_mapped_as_turned_and_reported(board):
    _, rig, sim = board
    upright = anaglyph.calibrate(sim.captures, rig, pattern=(9, 6))
    boards = dict(sim.captures)
    boards["r0c1"] = np.ascontiguousarray(boards["r0c1"][::-1, ::-1])
    fits = anaglyph.calibrate(boards, rig, pattern=(9, 6))
    turned = fits["r0c1"]
    assert turned["seen"] == "turned 180°"
    assert abs(turned["rotation_deg"]) > 179.0
    assert upright["r0c1"]["seen"] == "upright" and abs(upright["r0c1"]["rotation_deg"]) < 1.0
    # The turned camera's map is the upright one after turning the pixel back.
    height, width = boards["r0c1"].shape[:2]

    def apply(h, x, y):
        p = h @ np.array([x, y, 1.0])
        return p[:2] / p[2]

    for x, y in [(20.0, 30.0), (128.0, 96.0), (230.0, 170.0)]:
        expected = apply(upright["r0c1"]["homography"], width - 1 - x, height - 1 - y)
        np.testing.assert_allclose(apply(turned["homography"], x, y), expected, atol=0.2)
    assert fits["r0c2"]["seen"] == "upright"


def test_find_board_gives_the_corners_calibrate_fits(board):
    _, rig, sim = board
    fits = anaglyph.calibrate(sim.captures, rig, pattern=(9, 6))
    corners = anaglyph.find_board(sim.captures["r0c0"], (9, 6))
    assert corners.shape == (54, 2) and corners.dtype == np.float64
    np.testing.assert_array_equal(corners, fits["r0c0"]["corners"])
    # Row by row as the image shows the board: x grows along a row, y down the rows.
    assert np.all(np.diff(corners[:9, 0]) > 0) and corners[9, 1] > corners[0, 1]
    with pytest.raises(anaglyph.UnusableError, match=r"camera image cannot be used: no 8x6 checkerboard .*"
                       r"is the board 9x6\?"):
        anaglyph.find_board(sim.captures["r0c0"], (8, 6))
    with pytest.raises(anaglyph.SettingError, match="pattern"):
        anaglyph.find_board(sim.captures["r0c0"], (1, 6))
