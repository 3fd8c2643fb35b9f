#!/usr/bin/env python3
"""Where a reconstruction's error lies: the pixels of one view grouped by the set of cameras
that see them, from the simulator's true disparities. Needs numpy.

A camera sees a pixel of the view when the point lands inside its frame and its own true
disparity there (at the nearest pixel) agrees within 1 px, the simulator's convention:
a point at (x, y) with disparity d appears at (x - dx*d, y - dy*d) in the camera whose
centre lies (dx, dy) disparity baselines away (a grid: dc columns and dr rows away,
(x - dc*d, y - dr*d*b_y/b_x)). Per group: share of pixels, PSNR of the band-mean squared
error (an unmeasured band counts as an error of 1) and share of the view's squared error.

Run: python3 scripts/error_by_visibility.py SIM RECON [RECON ...] [--view r0c0] [--groups 10]
(SIM from `anaglyph simulate`, each RECON from `anaglyph reconstruct`)."""
import argparse
import os
import tomllib

import numpy as np

from anaglyph_files import camera_layout, read_envi, read_pfm


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sim")
    parser.add_argument("recon", nargs="+")
    parser.add_argument("--view", default="r0c0")
    parser.add_argument("--groups", type=int, default=10)
    args = parser.parse_args()
    rig = tomllib.load(open(os.path.join(args.sim, "rig.toml"), "rb"))
    names, positions, unit, _ = camera_layout(rig)
    me = positions[names.index(args.view)]
    truth_dir = os.path.join(args.sim, "truth")
    disparity = read_pfm(os.path.join(truth_dir, f"{args.view}_disparity.pfm"))
    height, width = disparity.shape
    ys, xs = np.mgrid[0:height, 0:width]
    seen_by = np.zeros((height, width), dtype=np.int64)
    for k, (name, (px, py)) in enumerate(zip(names, positions)):
        other = read_pfm(os.path.join(truth_dir, f"{name}_disparity.pfm"))
        x = np.rint(xs - (px - me[0]) / unit * disparity).astype(int)
        y = np.rint(ys - (py - me[1]) / unit * disparity).astype(int)
        inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
        there = other[np.clip(y, 0, height - 1), np.clip(x, 0, width - 1)]
        seen = inside & (np.abs(there - disparity) < 1.0)
        seen_by |= seen.astype(np.int64) << k
    truth = read_envi(os.path.join(truth_dir, f"{args.view}.hdr"))
    errors = []
    for recon in args.recon:
        cube = read_envi(os.path.join(recon, "views", f"{args.view}.hdr"))
        squared = (cube - truth) ** 2
        squared[~np.isfinite(squared)] = 1.0
        errors.append(squared.mean(axis=2))
    psnr = lambda e: 10 * np.log10(1.0 / max(e.mean(), 1e-12))
    runs = [os.path.basename(os.path.normpath(r)) for r in args.recon]
    print(f"{args.view}: PSNR of the band-mean squared error, per set of cameras that see the pixel")
    print("| cameras (rig order, X = sees) | share of pixels | " +
          " | ".join(f"{n} PSNR (share of error)" for n in runs) + " |")
    print("|---|---|" + "---|" * len(runs))
    print("| all pixels | 100 % | " + " | ".join(f"{psnr(e):.2f} dB" for e in errors) + " |")
    codes, counts = np.unique(seen_by, return_counts=True)
    for k in np.argsort(-counts)[: args.groups]:
        code = codes[k]
        mask = seen_by == code
        pattern = "".join("X" if code >> k & 1 else "." for k in range(len(names)))
        cells = " | ".join(f"{psnr(e[mask]):.2f} dB ({e[mask].sum() / e.sum():.1%})" for e in errors)
        print(f"| `{pattern}` | {counts[k] / seen_by.size:.1%} | {cells} |")


if __name__ == "__main__":
    main()
