#!/usr/bin/env python3
"""Where a reconstruction's error lies: the pixels of one view grouped by the set of cameras
that see them, from the simulator's true disparities. Needs numpy.

A camera sees a pixel of the view when the point lands inside its frame and its own true
disparity there (at the nearest pixel) agrees within 1 px, the simulator's convention:
a point at (x, y) with disparity d appears at (x - dc*d, y - dr*d*b_y/b_x) in the camera
dr rows and dc columns away. Per group: share of pixels, PSNR of the band-mean squared
error (an unmeasured band counts as an error of 1) and share of the view's squared error.

Run: python3 scripts/error_by_visibility.py SIM RECON [RECON ...] [--view r0c0] [--groups 10]
(SIM from `anaglyph simulate`, each RECON from `anaglyph reconstruct`)."""
import argparse
import os
import re
import tomllib

import numpy as np


def read_pfm(path):
    with open(path, "rb") as f:
        if f.readline().strip() != b"Pf":
            raise SystemExit(f"{path}: not a one-channel PFM")
        width, height = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    return data.reshape(height, width)[::-1].astype(np.float64)


def read_envi(path_hdr):
    header = open(path_hdr).read()
    field = lambda name: int(re.search(rf"^{name}\s*=\s*(\d+)", header, re.M).group(1))
    width, height, bands = field("samples"), field("lines"), field("bands")
    if field("data type") != 4 or "interleave = bip" not in header:
        raise SystemExit(f"{path_hdr}: expected float32 BIP, as anaglyph writes")
    data = np.fromfile(path_hdr[:-4] + ".img", dtype="<f4")
    return data.reshape(height, width, bands).astype(np.float64)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sim")
    parser.add_argument("recon", nargs="+")
    parser.add_argument("--view", default="r0c0")
    parser.add_argument("--groups", type=int, default=10)
    args = parser.parse_args()
    rig = tomllib.load(open(os.path.join(args.sim, "rig.toml"), "rb"))
    rows, cols = rig["rows"], rig["cols"]
    ratio = rig["baseline_mm"]["vertical"] / rig["baseline_mm"]["horizontal"]
    row0, col0 = map(int, re.fullmatch(r"r(\d+)c(\d+)", args.view).groups())
    truth_dir = os.path.join(args.sim, "truth")
    disparity = read_pfm(os.path.join(truth_dir, f"{args.view}_disparity.pfm"))
    height, width = disparity.shape
    ys, xs = np.mgrid[0:height, 0:width]
    seen_by = np.zeros((height, width), dtype=np.int64)
    for r in range(rows):
        for c in range(cols):
            other = read_pfm(os.path.join(truth_dir, f"r{r}c{c}_disparity.pfm"))
            x = np.rint(xs - (c - col0) * disparity).astype(int)
            y = np.rint(ys - (r - row0) * ratio * disparity).astype(int)
            inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
            there = other[np.clip(y, 0, height - 1), np.clip(x, 0, width - 1)]
            seen = inside & (np.abs(there - disparity) < 1.0)
            seen_by |= seen.astype(np.int64) << (r * cols + c)
    truth = read_envi(os.path.join(truth_dir, f"{args.view}.hdr"))
    errors = []
    for recon in args.recon:
        cube = read_envi(os.path.join(recon, "views", f"{args.view}.hdr"))
        squared = (cube - truth) ** 2
        squared[~np.isfinite(squared)] = 1.0
        errors.append(squared.mean(axis=2))
    psnr = lambda e: 10 * np.log10(1.0 / max(e.mean(), 1e-12))
    names = [os.path.basename(os.path.normpath(r)) for r in args.recon]
    print(f"{args.view}: PSNR of the band-mean squared error, per set of cameras that see the pixel")
    print("| cameras (row by row, X = sees) | share of pixels | " +
          " | ".join(f"{n} PSNR (share of error)" for n in names) + " |")
    print("|---|---|" + "---|" * len(names))
    print("| all pixels | 100 % | " + " | ".join(f"{psnr(e):.2f} dB" for e in errors) + " |")
    codes, counts = np.unique(seen_by, return_counts=True)
    for k in np.argsort(-counts)[: args.groups]:
        code = codes[k]
        mask = seen_by == code
        pattern = " ".join("".join("X" if code >> (r * cols + c) & 1 else "." for c in range(cols))
                           for r in range(rows))
        cells = " | ".join(f"{psnr(e[mask]):.2f} dB ({e[mask].sum() / e.sum():.1%})" for e in errors)
        print(f"| `{pattern}` | {counts[k] / seen_by.size:.1%} | {cells} |")


if __name__ == "__main__":
    main()
