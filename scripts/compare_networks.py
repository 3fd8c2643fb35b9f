"""Two matching networks through `reconstruct`: renders the tabletop and the clutter
scene through the paper's 2x4, the 3x3 narrow-band and the hexagonal array at WxH
(seed 3, 30 % vignetting, the simulator's noise), reconstructs each with the built-in
network and with MODEL (`reconstruct --model`), and prints per render and network the
mean reflectance PSNR (`anaglyph eval`) and the disparity maps' bad-1 against the truth
(all pixels of all views; an unknown disparity counts as wrong).

    cargo build --release
    python scripts/compare_networks.py MODEL [WxH] [ANAGLYPH]

WxH default 320x240; ANAGLYPH: the binary (default target/release/anaglyph). Needs numpy.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from anaglyph_files import read_pfm

RIGS = ("paper-2x4", "mono-3x3", "hexagon-7")
SCENES = ("tabletop", "clutter")


def bad1(truth: Path, recon: Path) -> float:
    wrong, total = 0, 0
    for true_map in sorted((truth / "truth").glob("*_disparity.pfm")):
        view = true_map.name.removesuffix("_disparity.pfm")
        expected = read_pfm(str(true_map))
        got = read_pfm(str(recon / "disparity" / f"{view}.pfm"))
        known = np.isfinite(expected)
        error = np.abs(np.where(np.isfinite(got), got, np.inf) - expected)[known]
        wrong += int(np.count_nonzero(~(error <= 1.0)))
        total += int(known.sum())
    return 100.0 * wrong / max(total, 1)


def main() -> None:
    model = sys.argv[1]
    size = sys.argv[2] if len(sys.argv) > 2 else "320x240"
    anaglyph = sys.argv[3] if len(sys.argv) > 3 else "target/release/anaglyph"
    quiet = dict(check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    print("| render | built-in: PSNR, bad-1 | MODEL: PSNR, bad-1 |")
    print("|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for rig in RIGS:
            for scene in SCENES:
                sim = Path(tmp) / f"{rig}-{scene}"
                subprocess.run(
                    [anaglyph, "simulate", "--scene", scene, "--rig", rig, "--size", size,
                     "--seed", "3", "--vignetting", "0.3", "--out", str(sim)],
                    **quiet,
                )
                cells = []
                for name, extra in (("builtin", []), ("model", ["--model", model])):
                    recon = sim / f"recon-{name}"
                    subprocess.run(
                        [anaglyph, "reconstruct", "--rig", str(sim / "rig.toml"), "--captures",
                         str(sim / "captures"), "--white", str(sim / "white"), *extra,
                         "--out", str(recon)],
                        **quiet,
                    )
                    scores = sim / f"eval-{name}.json"
                    subprocess.run(
                        [anaglyph, "eval", "--truth", str(sim), "--recon", str(recon),
                         "--json", str(scores)],
                        **quiet,
                    )
                    psnr = json.loads(scores.read_text())["mean_psnr"]
                    cells.append(f"{psnr:.2f} dB, {bad1(sim, recon):.2f} %")
                print(f"| {rig} {scene} | {cells[0]} | {cells[1]} |", flush=True)


if __name__ == "__main__":
    main()
