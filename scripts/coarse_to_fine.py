"""Coarse-to-fine registration against the full search, on the simulator's truth: renders
the tabletop through RIG at WxH, registers it with `reconstruct --output registered`
three ways (`--coarse-to-fine off`, `--coarse-to-fine on`, and the true disparities as
the oracle), and prints for each run its wall time and peak memory (GNU time), the
disparity maps' bad-1 and median error against the truth (all pixels of all views), and
the registered stacks' PSNR against the oracle's (pixels both see, peak 1).

    cargo build --release
    python scripts/coarse_to_fine.py [RIG] [WxH] [ANAGLYPH] [MODES] [--one-response]

RIG: a preset (mono-3x3, hexagon-7, paper-2x4; default mono-3x3); WxH default
1600x1200; ANAGLYPH: the binary (default target/release/anaglyph); MODES: the
registrations to run, `off,on` (default) or one of them. `--one-response` registers
through the rig without its filter curves, white boards and exposures (every camera of
the sensor's one response, as a registration-only run of a monochrome array knows it).
Needs numpy and /usr/bin/time.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np


def pfm(path: Path) -> np.ndarray:
    with open(path, "rb") as f:
        assert f.readline().strip() == b"Pf", path
        width, height = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    return np.flipud(data.reshape(height, width))


def envi(header: Path) -> np.ndarray:
    fields = {}
    for line in header.read_text().splitlines():
        if "=" in line:
            key, value = line.split("=", 1)
            fields[key.strip()] = value.strip()
    assert fields["interleave"] == "bip" and fields["data type"] == "4", header
    shape = (int(fields["lines"]), int(fields["samples"]), int(fields["bands"]))
    return np.fromfile(header.with_suffix(".img"), dtype="<f4").reshape(shape)


def timed(command: list[str]) -> tuple[float, float]:
    """Wall seconds and peak resident GB of `command` (GNU time)."""
    out = subprocess.run(
        ["/usr/bin/time", "-f", "%e %M", *command],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    wall, kb = out.stderr.strip().splitlines()[-1].split()
    return float(wall), float(kb) / 1024**2


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("rig", nargs="?", default="mono-3x3")
    parser.add_argument("size", nargs="?", default="1600x1200")
    parser.add_argument("binary", nargs="?", default="target/release/anaglyph")
    parser.add_argument("modes", nargs="?", default="off,on")
    parser.add_argument("--one-response", action="store_true")
    args = parser.parse_args()
    rig, size, binary, modes = args.rig, args.size, args.binary, args.modes.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        sim = Path(tmp) / "sim"
        subprocess.run(
            [binary, "simulate", "--scene", "tabletop", "--rig", rig, "--size", size,
             "--out", str(sim)],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        rig_file = sim / "rig.toml"
        if args.one_response:
            rig_file = sim / "rig-one-response.toml"
            lines = (sim / "rig.toml").read_text().splitlines()
            dropped = re.compile(r"^(filter|white|exposure|illuminant) =")
            rig_file.write_text("\n".join(l for l in lines if not dropped.match(l)) + "\n")
        base = [binary, "reconstruct", "--rig", str(rig_file), "--output", "registered"]
        runs = {
            name: ["--coarse-to-fine", mode]
            for name, mode in (("full search", "off"), ("coarse to fine", "on"))
            if mode in modes
        }
        runs["true disparities"] = ["--true-disparity", str(sim)]
        results = {}
        for name, extra in runs.items():
            out = Path(tmp) / name.replace(" ", "-")
            results[name] = (out, *timed([*base, *extra, "--out", str(out)]))
        oracle = results["true disparities"][0]
        views = sorted(p.stem for p in (oracle / "registered").glob("*.hdr"))
        kind = ", one response" if args.one_response else ""
        print(f"{rig}{kind} at {size}, {len(views)} views, `reconstruct --output registered`:")
        for name, (out, wall, gb) in results.items():
            line = f"  {name:17s} {wall:6.1f} s {gb:5.2f} GB"
            if name != "true disparities":
                errors = np.concatenate([
                    np.abs(pfm(out / "disparity" / f"{v}.pfm")
                           - pfm(sim / "truth" / f"{v}_disparity.pfm")).ravel()
                    for v in views
                ])
                errors = np.where(np.isfinite(errors), errors, np.inf)
                psnr = []
                for v in views:
                    a = envi(out / "registered" / f"{v}.hdr")
                    b = envi(oracle / "registered" / f"{v}.hdr")
                    both = np.isfinite(a) & np.isfinite(b)
                    mse = float(np.mean((a[both] - b[both]) ** 2))
                    psnr.append(10 * np.log10(1.0 / mse))
                line += (f"  bad-1 {100 * np.mean(errors > 1):5.2f} %"
                         f"  median error {np.median(errors):.3f} px"
                         f"  registered PSNR {np.mean(psnr):.2f} dB"
                         f" ({min(psnr):.2f} to {max(psnr):.2f})")
            print(line, flush=True)


if __name__ == "__main__":
    main()
