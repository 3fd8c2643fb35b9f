"""Readers of anaglyph's files for the scripts in this folder: one-channel PFM disparity
maps, float32 ENVI cubes and a rig's camera layout. Needs numpy."""
import math
import re

import numpy as np


def read_pfm(path):
    """A one-channel PFM as a float64 array, top row first."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"Pf":
            raise SystemExit(f"{path}: not a one-channel PFM")
        width, height = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    return data.reshape(height, width)[::-1].astype(np.float64)


def read_envi(path):
    """An ENVI cube as height × width × bands float64; `path` is the .hdr or its stem."""
    base = path[:-4] if path.endswith(".hdr") else path
    header = open(base + ".hdr").read()
    field = lambda name: int(re.search(rf"^{name}\s*=\s*(\d+)", header, re.M).group(1))
    width, height, bands = field("samples"), field("lines"), field("bands")
    if field("data type") != 4 or "interleave = bip" not in header:
        raise SystemExit(f"{base}.hdr: expected float32 BIP, as anaglyph writes")
    data = np.fromfile(base + ".img", dtype="<f4")
    return data.reshape(height, width, bands).astype(np.float64)


def camera_layout(rig):
    """A parsed rig TOML's cameras in rig order as (names, positions in mm, the disparity
    baseline in mm, the reference's index): a grid row-major, free positions in file order."""
    entries = rig["camera"]
    if "rows" in rig:
        b = rig["baseline_mm"]
        entries = sorted(entries, key=lambda c: (c["row"], c["col"]))
        names = [c.get("name", f"r{c['row']}c{c['col']}") for c in entries]
        positions = [(c["col"] * b["horizontal"], c["row"] * b["vertical"]) for c in entries]
        unit = b["horizontal"]
    else:
        names = [c.get("name", f"cam{k}") for k, c in enumerate(entries)]
        positions = [tuple(c["position_mm"]) for c in entries]
        unit = min(math.dist(a, b) for i, a in enumerate(positions) for b in positions[i + 1:])
    reference = next((k for k, c in enumerate(entries) if c.get("reference")), 0)
    return names, positions, unit, reference
