#!/usr/bin/env python3
"""A narrow-band array preset end to end, as a user runs it: the rig preset (`hexagon-7` or
`mono-3x3`: monochrome cameras 40 mm apart, f = 1000 px, the centre one the reference)
rendered by `anaglyph simulate` on the tabletop, calibrated to its own rendered
checkerboard (the scene preset `checkerboard`, 1.6 m) by `anaglyph calibrate`, and its
reference view reconstructed with the fitted and with the true homographies. Prints PSNR
against the truth, bad-1 of the reference's disparity on the pixels every camera sees, the
distance between the two runs' registered stacks, and with --all the time of every view.
Needs numpy and pillow (for --figure), and a release build.

    python3 scripts/preset_array.py --rig hexagon-7 --size 640x480 --figure docs/hexagonal_array.png
    python3 scripts/preset_array.py --rig mono-3x3 --size 800x600 --all=-16:16
"""
import argparse, json, os, re, subprocess, sys, tempfile, tomllib
import numpy as np
from anaglyph_files import camera_layout, read_envi, read_pfm

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "anaglyph")
PLANE_MM = 1600.0  # the checkerboard preset's distance


def run(work, *args):
    out = subprocess.run([BIN, *args], cwd=work, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"anaglyph {' '.join(args)} failed:\n{out.stderr}")
    return out.stdout


def write_true_homographies(work, names, positions, reference, focal):
    """Each camera's homography onto the reference through the plane: a shift f·Δp / d."""
    os.makedirs(os.path.join(work, "truecal"), exist_ok=True)
    ref = positions[reference]
    for name, (x, y) in zip(names, positions):
        shift = [focal * (p - q) / PLANE_MM for p, q in zip((x, y), ref)]
        h = [[1, 0, shift[0]], [0, 1, shift[1]], [0, 0, 1]]
        json.dump({"homography": h}, open(os.path.join(work, f"truecal/{name}.json"), "w"))


def seen_by_all(truth, positions, reference, unit):
    """Pixels of the reference whose point every other camera sees (truth within 1 px)."""
    t = truth[reference]
    h, w = t.shape
    ys, xs = np.mgrid[0:h, 0:w]
    seen = np.isfinite(t)
    for k, p in enumerate(positions):
        if k == reference:
            continue
        sx, sy = [(a - b) / unit for a, b in zip(positions[reference], p)]
        px, py = np.rint(xs + sx * t).astype(int), np.rint(ys + sy * t).astype(int)
        inside = (px >= 0) & (py >= 0) & (px < w) & (py < h)
        agree = np.zeros_like(seen)
        agree[inside] = np.abs(truth[k][py[inside], px[inside]] - t[inside]) <= 1
        seen &= agree
    return seen


def figure(work, view, out):
    from PIL import Image
    height, gap = 300, 8
    sheet = Image.open(os.path.join(work, "sim/contact_sheet.png")).convert("RGB")
    sheet = sheet.resize((round(sheet.width * height / sheet.height), height), Image.LANCZOS)
    disparity = Image.open(os.path.join(work, f"fitted/disparity/{view}.png")).convert("RGB")
    size = (round(disparity.width * height / disparity.height), height)
    disparity = disparity.resize(size, Image.LANCZOS)
    stack = read_envi(os.path.join(work, f"fitted/registered/{view}"))
    last = stack.shape[2] - 1
    rgb = np.stack([stack[..., last], stack[..., last // 2], stack[..., 0]], -1)
    rgb = np.nan_to_num(rgb / np.nanpercentile(rgb, 99.5), nan=0).clip(0, 1) ** (1 / 2.2)
    stacked = Image.fromarray((rgb * 255).astype(np.uint8)).resize(size, Image.LANCZOS)
    panels = (sheet, disparity, stacked)
    canvas = Image.new("RGB", (sum(p.width for p in panels) + 4 * gap, height + 2 * gap), "white")
    x = gap
    for panel in panels:
        canvas.paste(panel, (x, gap))
        x += panel.width + gap
    canvas.quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                    dither=Image.Dither.NONE).save(out, optimize=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rig", default="hexagon-7", choices=["hexagon-7", "mono-3x3"])
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--work", default=None)
    parser.add_argument("--figure", default=None, help="write the picture of the README here")
    parser.add_argument("--all", default=None, metavar="MIN:MAX",
                        help="also reconstruct every view over this range, timed")
    args = parser.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="anaglyph-preset-")
    os.makedirs(work, exist_ok=True)
    for scene, out in (("tabletop", "sim"), ("checkerboard", "board")):
        run(work, "simulate", "--scene", scene, "--rig", args.rig, "--size", args.size,
            "--out", out, "--force")
    rig = tomllib.load(open(os.path.join(work, "sim/rig.toml"), "rb"))
    names, positions, unit, reference = camera_layout(rig)
    focal = rig["focal_length_px"]
    view = names[reference]
    write_true_homographies(work, names, positions, reference, focal)
    print(run(work, "calibrate", "--checkerboard", "9x6", "--images", "board/captures",
              "--rig", "sim/rig.toml", "--out", "calib", "--force").strip())
    plane = focal * unit / PLANE_MM
    truth = [read_pfm(os.path.join(work, f"sim/truth/{n}_disparity.pfm")) - plane for n in names]
    seen = seen_by_all(truth, positions, reference, unit)
    for calibration, out in (("calib", "fitted"), ("truecal", "oracle")):
        printed = run(work, "reconstruct", "--rig", "sim/rig.toml", "--calibration",
                      calibration, "--views", view, "--output", "both", "--out", out,
                      "--force")
        lines = [l for l in printed.splitlines() if "search range" in l or "agree" in l
                 or l.startswith("wrote")]
        report = run(work, "eval", "--truth", "sim", "--recon", out)
        psnr = re.search(r"PSNR ([\d.]+) dB", report).group(1)
        error = np.abs(read_pfm(os.path.join(work, f"{out}/disparity/{view}.pfm")) - truth[reference])
        bad = np.mean(~(error[seen] <= 1.0)) * 100
        print(f"{out}: {view} {psnr} dB, bad-1 {bad:.2f} % of the {seen.mean() * 100:.1f} % "
              "of pixels every camera sees")
        print("  " + "\n  ".join(lines))
    a = read_envi(os.path.join(work, f"fitted/registered/{view}"))
    b = read_envi(os.path.join(work, f"oracle/registered/{view}"))
    both = np.isfinite(a) & np.isfinite(b)
    distance = 10 * np.log10(1.0 / np.mean((a[both] - b[both]) ** 2))
    print(f"registered stacks of the two runs: {distance:.1f} dB PSNR apart (peak 1)")
    if args.all:
        printed = run(work, "reconstruct", "--rig", "sim/rig.toml", "--calibration", "calib",
                      "--disp-range", args.all, "--out", "all", "--force")
        print("every view:\n  " + "\n  ".join(
            l.strip() for l in printed.splitlines() if "registration:" in l or "wrote" in l))
    if args.figure:
        figure(work, view, args.figure)
        print(f"wrote {args.figure}")
    print(f"work files in {work}")


if __name__ == "__main__":
    main()
