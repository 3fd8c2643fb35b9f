"""What Dask costs over the work it runs: `anaglyph.dask.reconstruct_frames` of FRAMES
frames of the tabletop (the paper's rig, its field of view kept; a new noise seed per
frame) at WxH on a LocalCluster of WORKERS processes with one thread each, one frame per
task. The overhead is the share of the workers' wall time (call wall time × workers) not
spent inside the tasks' reconstructions (the per-frame times the tasks report); the
cluster is started, and its workers have imported anaglyph, before the clock starts.

    pip install ./crates/anaglyph-py "dask[distributed]"
    python scripts/dask_overhead.py [FRAMES] [WxH] [WORKERS]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from distributed import Client, LocalCluster

import anaglyph
import anaglyph.dask


def scaled_rig(width: int) -> anaglyph.Rig:
    """The paper's rig with its focal length scaled to `width` px (made for 640 px)."""
    lines = []
    for line in anaglyph.Rig.preset("paper-2x4").to_toml().splitlines():
        if line.startswith("focal_length_px"):
            line = f"focal_length_px = {float(line.split('=')[1]) * width / 640}"
        lines.append(line)
    return anaglyph.Rig.from_toml("\n".join(lines))


def main() -> None:
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    width, height = map(int, (sys.argv[2] if len(sys.argv) > 2 else "160x120").split("x"))
    workers = int(sys.argv[3]) if len(sys.argv) > 3 else 2
    rig = scaled_rig(width)
    sims = [anaglyph.simulate("tabletop", rig=rig, size=(width, height), seed=s) for s in range(frames)]
    clip = {s: sim.captures for s, sim in enumerate(sims)}
    with LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=":0") as cluster:
        with Client(cluster) as client:
            client.run(lambda: __import__("anaglyph"))
            with tempfile.TemporaryDirectory() as tmp:
                started = time.perf_counter()
                run = anaglyph.dask.reconstruct_frames(
                    rig, clip, Path(tmp) / "clip.zarr", client=client, batch=1,
                    whites=sims[0].whites, progress=False,
                )
                wall = time.perf_counter() - started
    busy = sum(r.seconds for r in run.frames)
    print(
        f"{frames} frames at {width}x{height} on {workers} workers x 1 thread: wall {wall:.2f} s, "
        f"tasks {busy:.2f} s, overhead {100 * (1 - busy / (wall * workers)):.1f} % of the workers' time"
    )


if __name__ == "__main__":
    main()
