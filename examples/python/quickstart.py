"""anaglyph from Python: simulate the tabletop through the paper's 2x4 rig, reconstruct the
corner view's reflectance cube, plot three pixels' spectra against the truth, open the
written cube with Spectral Python and label the light field with xarray.

    pip install ./crates/anaglyph-py matplotlib spectral xarray
    python examples/python/quickstart.py [OUT_DIR]

Writes OUT_DIR/quickstart.png (the figure in the README) and OUT_DIR/r0c0.hdr + .img.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import anaglyph

out = Path(sys.argv[1] if len(sys.argv) > 1 else "quickstart-out")
out.mkdir(parents=True, exist_ok=True)

# The scene through the paper's rig: 16-bit captures with noise and unknown exposures.
sim = anaglyph.simulate("tabletop", rig="paper-2x4", size=(640, 480))
# The light field of the corner view, from the captures and white boards alone.
rec = anaglyph.reconstruct(sim.rig, sim.captures, whites=sim.whites, views=["r0c0"])
cube, truth = rec["r0c0"].cube, sim.reflectance["r0c0"]  # (480, 640, 24), bands last
seen = np.isfinite(cube)
psnr = 10 * np.log10(1 / np.mean((cube[seen] - truth[seen]) ** 2))
print(f"r0c0: {cube.shape}, {rec.wavelengths[0]:.0f}-{rec.wavelengths[-1]:.0f} nm, PSNR {psnr:.2f} dB")

# Three pixels' spectra against the truth, beside the view's sRGB-ish rendering.
pixels = {"chart, yellow": (266, 216), "chart, blue": (380, 222), "saucer": (541, 428)}
fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.6))
rgb = np.nan_to_num(cube[..., [20, 11, 3]]) / np.nanpercentile(cube[..., [20, 11, 3]], 99)
left.imshow(np.clip(rgb, 0, 1) ** (1 / 2.2))
for (label, (x, y)), colour in zip(pixels.items(), ["goldenrod", "C0", "C3"]):
    left.plot(x, y, "o", mfc="none", mec="white", ms=10)
    left.annotate(label, (x + 8, y - 8), color="white")
    right.plot(rec.wavelengths, truth[y, x], "--", color=colour, label=f"{label}: truth")
    right.plot(rec.wavelengths, cube[y, x], "-", color=colour, label=f"{label}: anaglyph")
left.set_axis_off()
left.set_title("r0c0, bands 610 / 538 / 474 nm")
right.set(xlabel="wavelength (nm)", ylabel="reflectance", title=f"spectra (view PSNR {psnr:.1f} dB)")
right.legend(fontsize=7)
fig.tight_layout()
fig.savefig(out / "quickstart.png", dpi=110)

# The cube as ENVI with its wavelengths, opened by Spectral Python.
anaglyph.write_envi(out / "r0c0.hdr", cube, wavelengths=rec.wavelengths.tolist())
try:
    import spectral

    image = spectral.open_image(str(out / "r0c0.hdr"))
    print(f"Spectral Python: {image.shape}, bands {image.bands.centers[0]}-{image.bands.centers[-1]} nm")
except ImportError:
    print("(pip install spectral to open the cube with Spectral Python)")

# The light field as an xarray Dataset: dims (view, y, x, wavelength).
try:
    ds = rec.to_xarray()
    print(ds["reflectance"].sel(view="r0c0", wavelength=slice(500, 600)).mean(("y", "x")).round(3).values)
except ImportError:
    print("(pip install xarray for Reconstruction.to_xarray)")
