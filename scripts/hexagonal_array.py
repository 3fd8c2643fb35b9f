#!/usr/bin/env python3
"""The hexagonal array of the README, end to end as a user runs it: the rig preset
`hexagon-7` (seven narrow-band monochrome cameras 40 mm apart, filters 440 to 620 nm, the
centre one the reference) rendered at 640x480 by `anaglyph simulate`, calibrated to its own
rendered checkerboard (the scene preset `checkerboard`, 1.6 m) by `anaglyph calibrate`, and reconstructed (centre view) with the fitted and with the
true homographies. Prints PSNR against the truth, bad-1 of the centre's disparity on the
pixels every camera sees, the distance between the two runs' registered stacks, and writes
docs/hexagonal_array.png. Needs numpy and pillow, and a release build.

    python3 scripts/hexagonal_array.py [--work DIR] [--size 640x480]
"""
import argparse, json, math, os, re, subprocess, sys, tempfile
import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "anaglyph")
SPACING_MM, FOCAL_PX, PLANE_MM = 40.0, 1000.0, 1600.0  # as data/rigs/hexagon-7.toml
CENTRES_NM = [440, 470, 500, 530, 560, 590, 620]


def positions():
    """The centre, then the ring counter-clockwise from the right (y down)."""
    ring = [(SPACING_MM * math.cos(k * math.pi / 3), SPACING_MM * math.sin(k * math.pi / 3))
            for k in range(6)]
    return [(0.0, 0.0)] + ring


def name(k):
    return f"nb{CENTRES_NM[k]}"


def run(work, *args):
    out = subprocess.run([BIN, *args], cwd=work, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"anaglyph {' '.join(args)} failed:\n{out.stderr}")
    return out.stdout


def write_true_homographies(work):
    os.makedirs(os.path.join(work, "truecal"), exist_ok=True)
    for k, (x, y) in enumerate(positions()):
        shift = [FOCAL_PX * p / PLANE_MM for p in (x, y)]
        h = [[1, 0, shift[0]], [0, 1, shift[1]], [0, 0, 1]]
        json.dump({"homography": h}, open(os.path.join(work, f"truecal/{name(k)}.json"), "w"))


def read_pfm(path):
    with open(path, "rb") as f:
        assert f.readline().strip() == b"Pf"
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.fromfile(f, dtype="<f4" if scale < 0 else ">f4").reshape(h, w)
    return data[::-1]


def read_envi(base):
    header = open(base + ".hdr").read()
    field = lambda key: int(re.search(key + r"\s*=\s*(\d+)", header).group(1))
    w, h, b = field("samples"), field("lines"), field("bands")
    data = np.fromfile(base + ".img", dtype="<f4")
    layout = re.search(r"interleave\s*=\s*(\w+)", header).group(1)
    if layout == "bip":
        return data.reshape(h, w, b)
    if layout == "bsq":
        return data.reshape(b, h, w).transpose(1, 2, 0)
    return data.reshape(h, b, w).transpose(0, 2, 1)


def seen_by_all(truth):
    """Pixels of the centre view whose point every other camera sees (truth within 1 px)."""
    t = truth[0]
    h, w = t.shape
    ys, xs = np.mgrid[0:h, 0:w]
    seen = np.isfinite(t)
    for k, (x, y) in enumerate(positions()):
        if k == 0:
            continue
        sx, sy = -x / SPACING_MM, -y / SPACING_MM
        px, py = np.rint(xs + sx * t).astype(int), np.rint(ys + sy * t).astype(int)
        inside = (px >= 0) & (py >= 0) & (px < w) & (py < h)
        agree = np.zeros_like(seen)
        agree[inside] = np.abs(truth[k][py[inside], px[inside]] - t[inside]) <= 1
        seen &= agree
    return seen


def figure(work, out):
    height, gap = 300, 8
    sheet = Image.open(os.path.join(work, "sim/contact_sheet.png")).convert("RGB")
    sheet = sheet.resize((round(sheet.width * height / sheet.height), height), Image.LANCZOS)
    disparity = Image.open(os.path.join(work, f"fitted/disparity/{name(0)}.png")).convert("RGB")
    size = (round(disparity.width * height / disparity.height), height)
    disparity = disparity.resize(size, Image.LANCZOS)
    stack = read_envi(os.path.join(work, f"fitted/registered/{name(0)}"))
    rgb = np.stack([stack[..., 6], stack[..., 3], stack[..., 0]], -1)  # 620, 530, 440 nm
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
    parser.add_argument("--work", default=None)
    parser.add_argument("--size", default="640x480")
    args = parser.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="anaglyph-hexagon-")
    os.makedirs(work, exist_ok=True)
    write_true_homographies(work)
    for scene, out in (("tabletop", "sim"), ("checkerboard", "board")):
        run(work, "simulate", "--scene", scene, "--rig", "hexagon-7", "--size", args.size,
            "--out", out, "--force")
    print(run(work, "calibrate", "--checkerboard", "9x6", "--images", "board/captures",
              "--rig", "sim/rig.toml", "--out", "calib", "--force").strip())
    plane = FOCAL_PX * SPACING_MM / PLANE_MM
    truth = [read_pfm(os.path.join(work, f"sim/truth/{name(k)}_disparity.pfm")) - plane
             for k in range(7)]
    seen = seen_by_all(truth)
    for calibration, out in (("calib", "fitted"), ("truecal", "oracle")):
        printed = run(work, "reconstruct", "--rig", "sim/rig.toml", "--calibration",
                      calibration, "--views", name(0), "--output", "both", "--out", out,
                      "--force")
        lines = [l for l in printed.splitlines() if "search range" in l or "agree" in l
                 or l.startswith("wrote")]
        report = run(work, "eval", "--truth", "sim", "--recon", out)
        psnr = re.search(r"PSNR ([\d.]+) dB", report).group(1)
        error = np.abs(read_pfm(os.path.join(work, f"{out}/disparity/{name(0)}.pfm")) - truth[0])
        bad = np.mean(~(error[seen] <= 1.0)) * 100
        print(f"{out}: {name(0)} {psnr} dB, bad-1 {bad:.2f} % of the {seen.mean() * 100:.1f} % "
              "of pixels every camera sees")
        print("  " + "\n  ".join(lines))
    a = read_envi(os.path.join(work, f"fitted/registered/{name(0)}"))
    b = read_envi(os.path.join(work, f"oracle/registered/{name(0)}"))
    both = np.isfinite(a) & np.isfinite(b)
    distance = 10 * np.log10(1.0 / np.mean((a[both] - b[both]) ** 2))
    print(f"registered stacks of the two runs: {distance:.1f} dB PSNR apart (peak 1)")
    out = os.path.join(ROOT, "docs", "hexagonal_array.png")
    figure(work, out)
    print(f"wrote {out} (work files in {work})")


if __name__ == "__main__":
    main()
