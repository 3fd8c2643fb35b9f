"""Shared fixtures: the CLI binary the package is compared with, and small simulations."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

import anaglyph

REPO = Path(__file__).resolve().parents[3]
#: The simulation size of the comparisons: small enough for 2 cores, large enough that
#: registration has texture to match.
SIZE = (160, 120)


@pytest.fixture(scope="session")
def cli() -> Path:
    """The `anaglyph` binary of this checkout (built by `cargo build --release`)."""
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    path = Path(os.environ.get("ANAGLYPH_CLI", target / "release" / "anaglyph"))
    if not path.is_file():
        pytest.fail(f"{path}: no anaglyph binary; run `cargo build --release` first (or set ANAGLYPH_CLI)")
    return path


def run_cli(cli: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """Runs the CLI, failing the test with its output when it fails."""
    done = subprocess.run([str(cli), *args], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.fail(f"anaglyph {' '.join(args)} exited {done.returncode}:\n{done.stderr}")
    return done


def small_rig(preset: str, width: int) -> anaglyph.Rig:
    """A preset whose focal length is scaled to images `width` px wide, so that a small
    simulation keeps the preset's field of view and disparities (the presets are made
    for 640 px, the paper's rig, and 800 px, the narrow-band arrays)."""
    native = {"paper-2x4": 640, "mono-3x3": 800, "hexagon-7": 800}[preset]
    text = anaglyph.Rig.preset(preset).to_toml()
    lines = []
    for line in text.splitlines():
        if line.startswith("focal_length_px"):
            focal = float(line.split("=")[1])
            line = f"focal_length_px = {focal * width / native}"
        lines.append(line)
    return anaglyph.Rig.from_toml("\n".join(lines))


@pytest.fixture(scope="session")
def tabletop() -> anaglyph.Simulation:
    """The tabletop through the paper's rig (field of view kept), in memory."""
    return anaglyph.simulate("tabletop", rig=small_rig("paper-2x4", SIZE[0]), size=SIZE, seed=0)
