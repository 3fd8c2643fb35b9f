"""Temporal reuse, measured: FRAMES frames of the moving tabletop (`tabletop-moving`)
through RIG at WxH, reconstructed into a Zarr store with reuse (each frame starting from
the previous one's search range and scene priors) and without (every frame alone). Per
frame: the wall time of each run and the reference view's PSNR against the simulator's
truth; then the median time per frame of each run, their ratio, and the largest loss of
PSNR of a frame with reuse against the same frame alone.

    pip install "./crates/anaglyph-py[xarray]"
    python scripts/temporal_reuse.py [paper-2x4|mono-3x3] [FRAMES] [WxH]

The paper's rig keeps its field of view (its focal length, made for 640 px, is scaled to
the width); the reference view is r0c0 for it and r1c1 for the 3×3 array.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
import zarr

import anaglyph

REFERENCE = {"paper-2x4": "r0c0", "mono-3x3": "r1c1"}


def rig_at(name: str, width: int) -> anaglyph.Rig:
    """The preset; the paper's rig with its focal length scaled to `width` px."""
    rig = anaglyph.Rig.preset(name)
    if name != "paper-2x4":
        return rig
    lines = []
    for line in rig.to_toml().splitlines():
        if line.startswith("focal_length_px"):
            line = f"focal_length_px = {float(line.split('=')[1]) * width / 640}"
        lines.append(line)
    return anaglyph.Rig.from_toml("\n".join(lines))


def psnr(truth: np.ndarray, estimate: np.ndarray) -> float:
    """PSNR (peak 1) over the values both hold."""
    known = np.isfinite(truth) & np.isfinite(estimate)
    mse = float(np.mean((truth[known] - estimate[known]) ** 2))
    return 10 * np.log10(1.0 / mse)


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "paper-2x4"
    frames = int(sys.argv[2]) if len(sys.argv) > 2 else 30
    width, height = map(int, (sys.argv[3] if len(sys.argv) > 3 else "320x240").split("x"))
    rig, reference = rig_at(name, width), REFERENCE[name]
    sims = [
        anaglyph.simulate("tabletop-moving", rig=rig, size=(width, height), seed=1, frame=k)
        for k in range(frames)
    ]
    clip = {k: sim.captures for k, sim in enumerate(sims)}
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for reuse in (True, False):
            store = Path(tmp) / f"reuse-{reuse}.zarr"
            run = anaglyph.reconstruct_frames(
                rig, clip, store=store, whites=sims[0].whites, reuse=reuse, progress=False
            )
            view = list(zarr.open_array(store / "view")[:]).index(reference)
            cubes = zarr.open_array(store / "reflectance")
            scores = [psnr(sims[k].reflectance[reference], cubes[k, view]) for k in range(frames)]
            runs[reuse] = (run, scores)
    (with_reuse, psnr_reuse), (alone, psnr_alone) = runs[True], runs[False]
    print(f"{name}, tabletop-moving, {frames} frames at {width}x{height}, view {reference}")
    print("frame  alone s  reuse s  alone dB  reuse dB  reused")
    for k in range(frames):
        report = with_reuse.frames[k].reuse or {}
        what = (
            "cut"
            if report.get("cut")
            else "range {}, {} priors, {:.0f} % px".format(
                "full" if report.get("range_fallback") or not report.get("narrowed_range")
                else "{min}:{max}".format(**report["narrowed_range"]),
                report.get("priors_carried", 0),
                100 * report.get("reused_pixels", 0) / (len(rig.cameras) * width * height),
            )
            if report.get("previous")
            else "first"
        )
        print(
            f"{k:5d}  {alone.frames[k].seconds:7.2f}  {with_reuse.frames[k].seconds:7.2f}  "
            f"{psnr_alone[k]:8.2f}  {psnr_reuse[k]:8.2f}  {what}"
        )
    median_alone = statistics.median(f.seconds for f in alone.frames)
    median_reuse = statistics.median(f.seconds for f in with_reuse.frames)
    loss = max(a - r for a, r in zip(psnr_alone, psnr_reuse))
    print(
        f"median per frame: {median_alone:.2f} s alone, {median_reuse:.2f} s with reuse "
        f"({median_alone / median_reuse:.2f}x faster); largest PSNR loss of a frame {loss:.2f} dB"
    )


if __name__ == "__main__":
    main()
