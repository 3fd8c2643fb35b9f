"""What the Python package costs over the CLI: `anaglyph reconstruct` of the tabletop at
320x240 (the paper's rig, its field of view kept) by the CLI and by `anaglyph.reconstruct`,
alternating, each in a fresh process under /usr/bin/time -v (wall time and peak RSS).

    pip install ./crates/anaglyph-py && cargo build --release
    python scripts/python_overhead.py [RUNS] [WORK_DIR]

The Python process reads the same 16-bit PNG captures into numpy (anaglyph.read_image),
then times the `reconstruct` call alone; the CLI's figure is its whole process (reading,
reconstructing and writing its output folder), so the comparison favours the CLI.
Prints the median of RUNS runs of each.
"""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import anaglyph

REPO = Path(__file__).resolve().parents[1]
CLI = REPO / "target" / "release" / "anaglyph"
SIZE = (320, 240)

PYTHON_RUN = """
import sys, time, anaglyph
sim = sys.argv[1]
rig = anaglyph.Rig.load(sim + "/rig.toml")
names = [c["name"] for c in rig.cameras]
captures = {n: anaglyph.read_image(f"{sim}/captures/{n}.png") for n in names}
whites = {n: anaglyph.read_image(f"{sim}/white/{n}.png") for n in names}
start = time.perf_counter()
rec = anaglyph.reconstruct(rig, captures, whites=whites, progress=False)
print(f"CALL {time.perf_counter() - start:.3f}")
"""


def timed(command: list[str]) -> tuple[float, float, str]:
    """(wall seconds, peak RSS MB, stdout) of `command` under /usr/bin/time -v."""
    done = subprocess.run(["/usr/bin/time", "-v", *command], capture_output=True, text=True, check=True)
    wall = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", done.stderr)
    assert wall is not None, done.stderr
    hours, minutes, seconds = wall.groups()
    seconds_total = int(hours or 0) * 3600 + int(minutes) * 60 + float(seconds)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)
    assert rss is not None, done.stderr
    return seconds_total, int(rss.group(1)) / 1024, done.stdout


def main() -> None:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    work = Path(sys.argv[2] if len(sys.argv) > 2 else tempfile.mkdtemp(prefix="anaglyph-overhead-"))
    work.mkdir(parents=True, exist_ok=True)
    text = anaglyph.Rig.preset("paper-2x4").to_toml()
    text = text.replace("focal_length_px = 1800.0", f"focal_length_px = {1800.0 * SIZE[0] / 640}")
    (work / "rig.toml").write_text(text)
    sim = work / "sim"
    subprocess.run([str(CLI), "simulate", "--scene", "tabletop", "--rig", str(work / "rig.toml"),
                    "--size", f"{SIZE[0]}x{SIZE[1]}", "--out", str(sim), "--force"],
                   check=True, capture_output=True)
    cli, python_call, python_process = [], [], []
    for k in range(runs):
        wall, rss, _ = timed([str(CLI), "reconstruct", "--rig", str(sim / "rig.toml"),
                              "--out", str(work / "rec"), "--force"])
        cli.append((wall, rss))
        wall, rss, out = timed([sys.executable, "-c", PYTHON_RUN, str(sim)])
        call = float(re.search(r"CALL ([\d.]+)", out).group(1))
        python_call.append(call)
        python_process.append((wall, rss))
        print(f"run {k + 1}: CLI {cli[-1][0]:.2f} s, {cli[-1][1]:.0f} MB; "
              f"Python call {call:.2f} s, process {wall:.2f} s, {rss:.0f} MB", flush=True)
    median = statistics.median
    print(f"median of {runs}: CLI process {median(w for w, _ in cli):.2f} s "
          f"(peak {median(r for _, r in cli):.0f} MB); Python reconstruct call "
          f"{median(python_call):.2f} s, whole process {median(w for w, _ in python_process):.2f} s "
          f"(peak {median(r for _, r in python_process):.0f} MB)")


if __name__ == "__main__":
    main()
