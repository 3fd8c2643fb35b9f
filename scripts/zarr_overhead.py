"""What writing a Zarr store costs per frame: `anaglyph.reconstruct_frames` of FRAMES
frames of the moving tabletop (`tabletop-moving` through the paper's rig, its field of
view kept) at WxH into a store, with temporal reuse, writing OUTPUT (default `both`: cubes
and registered stacks, the most a frame writes; `reflectance` for cubes alone). Prints
per frame the call's time and the store's share of it, then the median share and the
store's size.

    pip install ./crates/anaglyph-py
    python scripts/zarr_overhead.py [FRAMES] [WxH] [OUTPUT]
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path

import anaglyph


def scaled_rig(width: int) -> anaglyph.Rig:
    """The paper's rig with its focal length scaled to `width` px (made for 640 px)."""
    lines = []
    for line in anaglyph.Rig.preset("paper-2x4").to_toml().splitlines():
        if line.startswith("focal_length_px"):
            line = f"focal_length_px = {float(line.split('=')[1]) * width / 640}"
        lines.append(line)
    return anaglyph.Rig.from_toml("\n".join(lines))


def main() -> None:
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    width, height = map(int, (sys.argv[2] if len(sys.argv) > 2 else "320x240").split("x"))
    output = sys.argv[3] if len(sys.argv) > 3 else "both"
    rig = scaled_rig(width)
    sims = [
        anaglyph.simulate("tabletop-moving", rig=rig, size=(width, height), seed=1, frame=k)
        for k in range(frames)
    ]
    clip = {k: sim.captures for k, sim in enumerate(sims)}
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "clip.zarr"
        run = anaglyph.reconstruct_frames(
            rig, clip, whites=sims[0].whites, output=output, store=store, progress=False
        )
        shares = []
        for r in run.frames:
            share = r.store_seconds / r.seconds
            shares.append(share)
            print(f"frame {r.frame}: {r.seconds:.2f} s, store {r.store_seconds:.3f} s ({100 * share:.1f} %)")
        size = sum(f.stat().st_size for f in store.rglob("*") if f.is_file())
        print(
            f"{width}x{height}, {frames} frames, {output}: median store share {100 * statistics.median(shares):.1f} % "
            f"of a frame; store {size / 2**20:.1f} MiB"
        )


if __name__ == "__main__":
    main()
