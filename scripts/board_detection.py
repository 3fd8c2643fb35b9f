"""Checkerboard detection on hard renders: anaglyph's detector (`anaglyph.find_board`, what
`calibrate` runs) against OpenCV's `findChessboardCornersSB` on the same captures.

Each case is a scene around a 9x6 board (10 x 7 squares of 80 mm at 1.6 m, a white
border, a grey wall behind) rendered by the simulator through the `mono-3x3` array (nine
viewpoints, sensor noise, unknown exposures; 8 x 8 samples a pixel at 800x600, 4 x 4 at
1600x1200) at 800x600 and 1600x1200; cameras that do not see every inner corner are not
counted. Defocus is a Gaussian blur (sigma 2 px at 800x600) of the capture. A detection
counts when all 54 corners come back and each lies within 2 px of a true corner
(projected from the scene's geometry); its error is the distance to the nearest true
corner. OpenCV is a benchmark dependency only:

    pip install opencv-python-headless
    python scripts/board_detection.py [--sizes 800x600,1600x1200] [--cases clean,cut,...]
        [--pattern 9x6]

`--pattern 11x8` renders the real-array issue's board instead (12 x 9 squares of 80 mm),
with the cut, the monitor and the clutter placed against its larger border the same way.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

import anaglyph

COLS, ROWS, SQUARE_MM, BOARD_Z_MM = 9, 6, 80.0, 1600.0
WALL = '[[object]]\nrectangle = {{ centre_mm = [0, 0, 2600], size_mm = [12000, 12000] }}\nmaterial = {{ srgb = [{wall}, {wall}, {wall}] }}\n'
BOARD = ('[[object]]\nrectangle = {{ centre_mm = [{x}, {y}, {z}], size_mm = [{width}, {height}], rotation_deg = [{rx}, {ry}, 0] }}\n'
         'material = {{ pattern = "checker", period_mm = 80, srgb = [{dark}, {dark}, {dark}], srgb2 = [{light}, {light}, {light}] }}\n')
# A white border around the board (a printed target's margin), just behind it.
BORDER = ('[[object]]\nrectangle = {{ centre_mm = [{x}, {y}, {z}], size_mm = [{border_width}, {border_height}], rotation_deg = [{rx}, {ry}, 0] }}\n'
          'material = {{ srgb = [{light}, {light}, {light}] }}\n')
# A monitor: a dark slab 600 mm tall whose lower edge touches the board's border.
MONITOR = '[[object]]\nrectangle = {{ centre_mm = [0, {y}, 1590], size_mm = [1400, 600] }}\nmaterial = {{ srgb = [0.02, 0.02, 0.02] }}\n'
# The white margin around the board's squares, on every side.
MARGIN_MM = 80.0
# Clutter: textured patches (CC0 textures) beside the board.
CLUTTER = ''.join(
    f'[[object]]\nrectangle = {{ centre_mm = [{x}, {y}, 1620], size_mm = [{w}, {h}] }}\nmaterial = {{ texture = "{t}", scale_mm = 300 }}\n'
    for x, y, w, h, t in [(-700, 0, 500, 900, "brick"), (700, 100, 500, 700, "grass"), (0, 560, 900, 300, "coffee")]
)


def rotation(degrees: tuple[float, float, float]) -> np.ndarray:
    """The simulator's rotation (scene/geometry.rs `rotation`), as rows."""
    a, b, c = (math.radians(d) for d in degrees)
    sa, ca, sb, cb, sc, cc = math.sin(a), math.cos(a), math.sin(b), math.cos(b), math.sin(c), math.cos(c)
    return np.array([
        [cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa],
        [sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa],
        [-sb, cb * sa, cb * ca],
    ])


def case(name: str) -> tuple[str, dict]:
    """The scene of a case and its board's placement."""
    width, height = (COLS + 1) * SQUARE_MM, (ROWS + 1) * SQUARE_MM
    board = dict(x=0.0, y=0.0, z=BOARD_Z_MM, rx=0.0, ry=0.0, dark=0.05, light=0.9,
                 width=width, height=height)
    monitor = MONITOR.format(y=-(height / 2 + MARGIN_MM + 300.0))
    # Slid left so that the board's outer squares reach 30 mm past the left edge of the
    # frames of the left and middle columns of cameras (their edges at -680 and -640 mm
    # at the board's distance), every inner corner in; cameras that lose inner corners
    # are not counted. For the 9x6 board, -310 mm.
    cut_x = -710.0 + width / 2
    extra, wall = "", 0.5
    if name == "cut":
        board["x"] = cut_x
    elif name == "office":
        # The real office capture's surroundings together: cut by the frame's left edge,
        # a monitor's dark edge above the board, clutter beside it.
        board["x"] = cut_x
        extra = monitor + CLUTTER
    elif name == "monitor":
        extra = monitor
    elif name == "clutter":
        extra = CLUTTER
    elif name == "low-contrast":
        board.update(dark=0.3, light=0.45)
        wall = 0.35
    elif name == "saturated":
        board.update(dark=0.2, light=1.0)
        wall = 1.0
    elif name == "tilt-30":
        board["ry"] = 30.0
    elif name == "tilt-45":
        board["ry"] = 45.0
    elif name not in ("clean", "defocus"):
        raise SystemExit(f"unknown case {name}")
    border = dict(board, z=board["z"] + 1.0, border_width=width + 2 * MARGIN_MM,
                  border_height=height + 2 * MARGIN_MM)
    scene = ('name = "board"\n' + WALL.format(wall=wall) + BORDER.format(**border)
             + BOARD.format(**board) + extra)
    return scene, board


def true_corners(board: dict, camera: np.ndarray, focal: float, size: tuple[int, int]) -> np.ndarray:
    """The board's inner corners projected into a camera at `camera` (mm) looking along +z,
    pixel centres at integers."""
    r = rotation((board["rx"], board["ry"], 0.0))
    axis_u, axis_v = r[:, 0], r[:, 1]
    centre = np.array([board["x"], board["y"], board["z"]])
    half_u, half_v = (COLS + 1) * SQUARE_MM / 2, (ROWS + 1) * SQUARE_MM / 2
    points = np.array([
        centre + axis_u * (i * SQUARE_MM - half_u) + axis_v * (j * SQUARE_MM - half_v)
        for j in range(1, ROWS + 1) for i in range(1, COLS + 1)
    ])
    d = points - camera
    x = focal * d[:, 0] / d[:, 2] + 0.5 * size[0] - 0.5
    y = focal * d[:, 1] / d[:, 2] + 0.5 * size[1] - 0.5
    return np.stack([x, y], axis=1)


def score(found: np.ndarray | None, truth: np.ndarray) -> np.ndarray | None:
    """Distances from each found corner to its nearest true corner, or None when the
    detection is incomplete or wrong (a corner over 2 px from every true one)."""
    if found is None or len(found) != len(truth):
        return None
    d = np.linalg.norm(found[:, None, :] - truth[None, :, :], axis=2).min(axis=1)
    return d if d.max() < 2.0 else None


def opencv(grey: np.ndarray) -> np.ndarray | None:
    image8 = cv2.normalize(grey, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    ok, corners = cv2.findChessboardCornersSB(image8, (COLS, ROWS), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    return corners.reshape(-1, 2).astype(np.float64) if ok else None


def ours(grey: np.ndarray) -> np.ndarray | None:
    try:
        return anaglyph.find_board(grey, (COLS, ROWS))
    except anaglyph.UnusableError:
        return None


def pattern(text: str) -> tuple[int, int]:
    """A board's inner corners, COLSxROWS, each at least 2."""
    try:
        cols, rows = (int(v) for v in text.split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected COLSxROWS, for example 11x8") from None
    if cols < 2 or rows < 2:
        raise argparse.ArgumentTypeError(f"{text!r}: a board has at least 2x2 inner corners")
    return cols, rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="800x600,1600x1200")
    parser.add_argument("--cases", default="clean,cut,monitor,clutter,office,low-contrast,saturated,tilt-30,tilt-45,defocus")
    parser.add_argument("--pattern", default="9x6", type=pattern, help="inner corners, COLSxROWS")
    args = parser.parse_args()
    global COLS, ROWS
    COLS, ROWS = args.pattern
    print("| case | size | anaglyph found | its median / largest error (px) | OpenCV SB found | its median / largest error (px) | seconds per capture (anaglyph / OpenCV) |")
    print("|---|---|---|---|---|---|---|")
    totals = {"anaglyph": [0, 0], "opencv": [0, 0]}
    for size_text in args.sizes.split(","):
        width, height = (int(v) for v in size_text.split("x"))
        text = anaglyph.Rig.preset("mono-3x3").to_toml()
        focal = 1000.0 * width / 800
        rig = anaglyph.Rig.from_toml(text.replace("focal_length_px = 1000.0", f"focal_length_px = {focal}"))
        for name in args.cases.split(","):
            scene, board = case(name)
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / "board.toml"
                path.write_text(scene)
                sim = anaglyph.simulate(str(path), rig=rig, size=(width, height), seed=3,
                                       supersampling=max(2, 8 * 800 // width))
            results = {"anaglyph": [], "opencv": []}
            seconds = {"anaglyph": 0.0, "opencv": 0.0}
            for cam in rig.cameras:
                grey = sim.captures[cam["name"]].astype(np.float32)
                if grey.ndim == 3:
                    grey = grey.mean(axis=2)
                if name == "defocus":
                    grey = cv2.GaussianBlur(grey, (0, 0), 2.0 * width / 800)
                grey = np.ascontiguousarray(grey / 65535.0, dtype=np.float32)
                x, y = cam["position_mm"]
                truth = true_corners(board, np.array([x, y, 0.0]), focal, (width, height))
                inside = (truth >= 3).all() and (truth[:, 0] <= width - 4).all() and (truth[:, 1] <= height - 4).all()
                if not inside:
                    continue  # a board that is not whole in the frame: not a detection to ask for
                for who, detect in (("anaglyph", ours), ("opencv", opencv)):
                    start = time.perf_counter()
                    found = detect(grey)
                    seconds[who] += time.perf_counter() - start
                    results[who].append(score(found, truth))
            cells = []
            for who in ("anaglyph", "opencv"):
                hits = [r for r in results[who] if r is not None]
                totals[who][0] += len(hits)
                totals[who][1] += len(results[who])
                errors = np.concatenate(hits) if hits else np.array([np.nan])
                cells += [f"{len(hits)}/{len(results[who])}", f"{np.median(errors):.3f} / {errors.max():.3f}"]
            n = max(1, len(results["anaglyph"]))
            print(f"| {name} | {width}x{height} | " + " | ".join(cells)
                  + f" | {seconds['anaglyph'] / n:.2f} / {seconds['opencv'] / n:.2f} |", flush=True)
    print()
    for who, (hit, total) in totals.items():
        print(f"{who}: {hit} of {total} boards found")


if __name__ == "__main__":
    main()
