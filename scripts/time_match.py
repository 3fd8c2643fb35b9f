"""Wall time, peak memory and per-stage times of `anaglyph match` on the tabletop's
741x500 pair with 64 disparities, for two binaries (and the second one also with
ANAGLYPH_NO_AMX=1, f32 where the CPU has AMX tiles), alternating, each run a fresh process
under /usr/bin/time -v.

    cargo build --release
    python3 scripts/time_match.py [RUNS] [BEFORE_BINARY] [AFTER_BINARY] [--model M] [--method NAME]

BEFORE_BINARY is another build (for example of an earlier commit, built with
CARGO_TARGET_DIR elsewhere); without it only the current build is timed, with and without
AMX. `--model M` and `--method NAME` also time the current build with the network M
(`match --model`) or the method NAME (`match --method`, for example `mccnn-lean`).
Prints the median and range of each figure over RUNS runs, and each map's bad-1 and
bad-2 against the simulator's truth.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def read_pfm(path: Path) -> tuple[int, int, list[float]]:
    with open(path, "rb") as f:
        if f.readline().strip() != b"Pf":
            raise ValueError(f"{path}: not a one-channel PFM")
        width, height = map(int, f.readline().split())
        scale = float(f.readline())
        order = "<" if scale < 0 else ">"
        data = f.read()
    values = list(struct.unpack(f"{order}{width * height}f", data[: 4 * width * height]))
    return width, height, values


def bad(truth: list[float], estimate: list[float], threshold: float) -> float:
    wrong = sum(1 for t, e in zip(truth, estimate) if not abs(e - t) <= threshold)
    return 100.0 * wrong / len(truth)


def main() -> None:
    parser = argparse.ArgumentParser(description="Times `anaglyph match` on the tabletop pair.")
    parser.add_argument("runs", nargs="?", type=int, default=5)
    parser.add_argument("before", nargs="?", type=Path)
    parser.add_argument("after", nargs="?", type=Path, default=REPO / "target/release/anaglyph")
    parser.add_argument("--model", type=Path, help="also time the current build with this network")
    parser.add_argument("--method", help="also time the current build with this method")
    args = parser.parse_args()
    if args.model is not None and not args.model.is_file():
        sys.exit(f"--model {args.model}: no such file")
    after = args.after.resolve()
    modes: dict[str, tuple[Path, dict[str, str], list[str]]] = {}
    if args.before is not None:
        modes["before"] = (args.before.resolve(), {}, [])
    modes["after, ANAGLYPH_NO_AMX=1"] = (after, {"ANAGLYPH_NO_AMX": "1"}, [])
    modes["after"] = (after, {}, [])
    if args.model is not None:
        model = args.model.resolve()
        modes[f"after, --model {model.name}"] = (after, {}, ["--model", str(model)])
    if args.method is not None:
        modes[f"after, --method {args.method}"] = (after, {}, ["--method", args.method])
    for binary, _, _ in modes.values():
        if not binary.is_file():
            sys.exit(f"{binary}: no such binary (run `cargo build --release` first)")
    work = Path(tempfile.mkdtemp(prefix="time_match-"))
    subprocess.run(
        [str(after), "simulate", "--scene", "tabletop", "--size", "741x500", "--out", "sim"],
        cwd=work,
        check=True,
        capture_output=True,
    )
    figures: dict[str, dict[str, list[float]]] = {m: {"wall": [], "peak MB": []} for m in modes}
    for _ in range(args.runs):
        for k, (name, (binary, env, extra)) in enumerate(modes.items()):
            out = subprocess.run(
                ["/usr/bin/time", "-v", str(binary), "match",
                 "--left", "sim/captures/r0c0.png", "--right", "sim/captures/r0c1.png",
                 "--disp-range", "0:64", "--out", f"d{k}.pfm", "--report", f"r{k}.json",
                 *extra],
                cwd=work, env={**os.environ, **env}, capture_output=True, text=True,
            )
            if out.returncode != 0:
                sys.exit(f"{name}: match failed:\n{out.stderr}")
            wall = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+(?:\.\d+)?)", out.stderr)
            rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr)
            figures[name]["wall"].append(60 * float(wall.group(1) or 0) + float(wall.group(2)))
            figures[name]["peak MB"].append(int(rss.group(1)) / 1024)
            for stage in json.loads((work / f"r{k}.json").read_text())["timings_s"]:
                figures[name].setdefault(stage["stage"], []).append(stage["seconds"])
    _, _, truth = read_pfm(work / "sim/truth/r0c0_disparity.pfm")
    for k, (name, stages) in enumerate(figures.items()):
        _, _, estimate = read_pfm(work / f"d{k}.pfm")
        print(f"{name}: bad-1 {bad(truth, estimate, 1):.2f} %, bad-2 {bad(truth, estimate, 2):.2f} %")
        for stage, values in stages.items():
            print(f"  {stage:18s} {statistics.median(values):8.3f}  ({min(values):.3f}-{max(values):.3f})")


if __name__ == "__main__":
    main()
