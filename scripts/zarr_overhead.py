"""What writing a Zarr store costs per frame: `anaglyph.reconstruct_frames` of FRAMES
frames of the moving tabletop (`tabletop-moving` through the paper's rig, its field of
view kept) at WxH, with temporal reuse, writing OUTPUT (default `both`: cubes and
registered stacks, the most a frame writes; `cube` for cubes alone) into a store, against
the same run returning its arrays instead (no store), alternately, REPEATS times each
(default 2). Each frame's write runs on a thread of its own while the next frame is
computed; prints per frame of the last run with the store the call's time, the write's
time on its thread and how long the next frame waited for it, then each run's wall time,
and the store's cost: each run with it against the run without it that followed.

    pip install ./crates/anaglyph-py
    python scripts/zarr_overhead.py [FRAMES] [WxH] [OUTPUT] [REPEATS]
"""

from __future__ import annotations

import shutil
import statistics
import sys
import tempfile
import time
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
    repeats = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    walls: dict[str, list[float]] = {"store": [], "arrays": []}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(repeats):
            for kind in walls:
                store = Path(tmp) / f"clip-{repeat}.zarr" if kind == "store" else None
                started = time.perf_counter()
                run = anaglyph.reconstruct_frames(
                    rig, clip, whites=sims[0].whites, output=output, store=store, progress=False
                )
                walls[kind].append(time.perf_counter() - started)
                if store is not None:
                    reports, size = run.frames, sum(f.stat().st_size for f in store.rglob("*") if f.is_file())
                    shutil.rmtree(store)
                del run
        for r in reports:
            print(
                f"frame {r.frame}: {r.seconds:.2f} s, its write {r.store_seconds:.3f} s, "
                f"waited for {r.store_wait_seconds:.3f} s"
            )
        for kind, values in walls.items():
            print(f"{kind}: " + ", ".join(f"{v:.2f} s" for v in values))
        # Each run with the store against the run without it just after (the machine's
        # speed drifts between runs by as much as the store costs).
        paired = [100 * (a / b - 1) for a, b in zip(walls["store"], walls["arrays"])]
        with_store, without = statistics.median(walls["store"]), statistics.median(walls["arrays"])
        print(
            f"{width}x{height}, {frames} frames, {output}: {with_store:.2f} s with the store, "
            f"{without:.2f} s without (runs paired: "
            + ", ".join(f"{d:+.1f} %" for d in paired)
            + f", median {statistics.median(paired):+.1f} %); "
            f"median write {statistics.median(r.store_seconds for r in reports):.3f} s, "
            f"median wait {statistics.median(r.store_wait_seconds for r in reports):.3f} s; "
            f"store {size / 2**20:.1f} MiB"
        )


if __name__ == "__main__":
    main()
