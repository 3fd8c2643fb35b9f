"""OpenCV's semi-global block matching (`cv2.StereoSGBM`) on the held-out pairs that
`examples/stereo_quality.rs` scores, with the same rules: bad-2.0 over the pixels whose
truth is known and below the searched range's last disparity, invalid pixels counted as
errors, the mean error of the pixels it did match, its density, and seconds per
megapixel per 100 disparities.

    ANAGLYPH_WRITE_PAIRS=pairs ANAGLYPH_COSTS=mccnn \\
        cargo run --release --example stereo_quality -- 12 256 192
    pip install opencv-python-headless
    python scripts/sgbm_baseline.py pairs [--block 5] [--mode hh|sgbm|3way]

Each float image is mapped to 8 bits between its own least and greatest value, as a user
with float captures would; SGBM's parameters are OpenCV's documented defaults for one
channel (P1 = 8·block², P2 = 32·block², uniqueness 10, speckle window 100 and range 2,
left-right difference 1) over the range the pairs were matched with. OpenCV is a
benchmark dependency only.
"""

from __future__ import annotations

import argparse
import csv
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from anaglyph_files import read_pfm

MODES = {
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
}


def eight_bits(image: np.ndarray) -> np.ndarray:
    finite = np.where(np.isfinite(image), image, np.nan)
    lo, hi = np.nanmin(finite), np.nanmax(finite)
    scaled = (np.nan_to_num(finite, nan=lo) - lo) / max(hi - lo, 1e-12)
    return np.clip(np.round(255.0 * scaled), 0, 255).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", type=Path, help="the folder ANAGLYPH_WRITE_PAIRS wrote")
    parser.add_argument("--block", type=int, default=5, help="SGBM's block size (odd)")
    parser.add_argument("--mode", choices=sorted(MODES), default="hh")
    args = parser.parse_args()
    if not (args.pairs / "index.tsv").is_file():
        raise SystemExit(f"{args.pairs}: no index.tsv (write the pairs with "
                         "ANAGLYPH_WRITE_PAIRS=DIR and the stereo_quality example)")
    with open(args.pairs / "index.tsv", newline="") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    if not rows:
        raise SystemExit(f"{args.pairs / 'index.tsv'}: no pairs listed")
    totals = defaultdict(lambda: {"bad": 0, "total": 0, "valid": 0, "error": 0.0,
                                  "seconds": 0.0, "mpx": 0.0, "disparities": 0, "pairs": 0})
    for row in rows:
        stem, max_disp = row["stem"], int(row["max_disp"])
        left = eight_bits(read_pfm(args.pairs / f"{stem}-left.pfm"))
        right = eight_bits(read_pfm(args.pairs / f"{stem}-right.pfm"))
        truth = read_pfm(args.pairs / f"{stem}-truth.pfm")
        block = args.block
        matcher = cv2.StereoSGBM_create(
            minDisparity=0,
            numDisparities=16 * ((max_disp + 15) // 16),
            blockSize=block,
            P1=8 * block * block,
            P2=32 * block * block,
            disp12MaxDiff=1,
            uniquenessRatio=10,
            speckleWindowSize=100,
            speckleRange=2,
            mode=MODES[args.mode],
        )
        started = time.perf_counter()
        raw = matcher.compute(left, right)
        seconds = time.perf_counter() - started
        disparity = raw.astype(np.float32) / 16.0
        disparity[raw < 0] = np.nan
        scored = np.isfinite(truth) & (truth < max_disp - 1.0)
        valid = scored & np.isfinite(disparity)
        bad = scored & ~(np.abs(disparity - truth) <= 2.0)
        t = totals[row["group"]]
        t["bad"] += int(bad.sum())
        t["total"] += int(scored.sum())
        t["valid"] += int(valid.sum())
        t["error"] += float(np.abs(disparity - truth)[valid].sum())
        t["seconds"] += seconds
        t["mpx"] += left.size / 1e6
        t["disparities"] = max_disp
        t["pairs"] += 1
    print(f"OpenCV {cv2.__version__} StereoSGBM, mode {args.mode}, block {args.block}, "
          f"on {args.pairs}:")
    print("| group | pairs | bad-2.0 % | avg error px (valid) | density % | s / Mpx / 100 disp |")
    print("|---|---|---|---|---|---|")
    for group, t in totals.items():
        total = max(t["total"], 1)
        per = t["seconds"] / t["mpx"] / (t["disparities"] / 100.0)
        error = t["error"] / max(t["valid"], 1)
        print(f"| {group} | {t['pairs']} | {100 * t['bad'] / total:.1f} | {error:.2f} | "
              f"{100 * t['valid'] / total:.1f} | {per:.3f} |")


if __name__ == "__main__":
    main()
