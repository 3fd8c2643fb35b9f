"""A moving clip through the paper's rig, reconstructed frame by frame into a Zarr store
and opened with xarray: the disparity of view r0c0 at frames 0, 10 and 20 beside the
simulator's truth (docs/sequence.png).

    pip install "./crates/anaglyph-py[xarray]" matplotlib
    python examples/python/sequence.py [OUT.png]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import xarray as xr

import anaglyph

SIZE = (320, 240)
FRAMES = (0, 10, 20)


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/sequence.png")
    # The paper's rig, its field of view kept at 320 px (its focal length is for 640 px).
    text = anaglyph.Rig.preset("paper-2x4").to_toml()
    rig = anaglyph.Rig.from_toml(text.replace("focal_length_px = 1800.0", "focal_length_px = 900.0"))
    sims = {k: anaglyph.simulate("tabletop-moving", rig=rig, size=SIZE, seed=1, frame=k) for k in FRAMES}
    clip = {k: sim.captures for k, sim in sims.items()}
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "clip.zarr"
        run = anaglyph.reconstruct_frames(rig, clip, store=store, whites=sims[0].whites, views=["r0c0"])
        ds = xr.open_zarr(store)
        estimated = {k: ds["disparity"].sel(frame=k, view="r0c0").values for k in FRAMES}
    fig, axes = plt.subplots(2, len(FRAMES), figsize=(3.2 * len(FRAMES), 5.2), constrained_layout=True)
    truth = {k: sims[k].disparity["r0c0"] for k in FRAMES}
    low = min(np.nanmin(t[np.isfinite(t)]) for t in truth.values())
    high = max(np.nanmax(t[np.isfinite(t)]) for t in truth.values())
    for col, k in enumerate(FRAMES):
        known = np.isfinite(estimated[k]) & np.isfinite(truth[k])
        bad = np.mean(np.abs(estimated[k][known] - truth[k][known]) > 1.0)
        for row, (image, title) in enumerate(
            [(estimated[k], f"frame {k}: estimated ({100 * bad:.0f} % off > 1 px)"), (truth[k], f"frame {k}: truth")]
        ):
            ax = axes[row, col]
            ax.imshow(image, cmap="magma", vmin=low, vmax=high)
            ax.set_title(title, fontsize=9)
            ax.set_axis_off()
    fig.suptitle("tabletop-moving through the paper's rig, view r0c0: disparity per column step", fontsize=10)
    fig.savefig(out, dpi=90)
    seconds = [r.seconds for r in run.frames]
    print(f"wrote {out}; {len(seconds)} frames, {np.median(seconds):.1f} s per frame (median)")


if __name__ == "__main__":
    main()
