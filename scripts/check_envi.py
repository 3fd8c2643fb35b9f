#!/usr/bin/env python3
"""Checks that anaglyph's ENVI output opens in Spectral Python and GDAL with the right
values and wavelengths. Needs `pip install numpy spectral` and GDAL's command-line tools
(`apt-get install gdal-bin`), and a release build. Run: python3 scripts/check_envi.py"""
import json, os, subprocess, sys, tempfile
import numpy as np
import spectral

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "anaglyph")


def main():
    tmp = tempfile.mkdtemp(prefix="anaglyph-envi-")
    rng = np.random.default_rng(0)
    C = rng.uniform(0.0, 0.2, size=(6, 4))
    S = rng.uniform(0.1, 0.9, size=(3, 5, 4))  # H × W × N
    np.save(os.path.join(tmp, "C.npy"), C)
    np.save(os.path.join(tmp, "P.npy"), (S @ C.T).astype(np.float32))
    subprocess.run([BIN, "demux", "--sensing", "C.npy", "--measurements", "P.npy", "--out", "S.hdr",
                    "--lambda", "0", "--wavelengths", "450:8"], cwd=tmp, check=True)
    img = spectral.envi.open(os.path.join(tmp, "S.hdr"))
    cube = img.load()
    assert cube.shape == (3, 5, 4), cube.shape
    assert np.allclose(cube, S, atol=1e-4), np.abs(cube - S).max()
    assert [float(w) for w in img.bands.centers] == [450, 458, 466, 474], img.bands.centers
    print("Spectral Python", spectral.__version__, ": shape", cube.shape, "max |error|", float(np.abs(cube - S).max()),
          "wavelengths", img.bands.centers, img.bands.band_unit)
    info = json.loads(subprocess.run(["gdalinfo", "-json", "-mm", os.path.join(tmp, "S.img")],
                                     check=True, capture_output=True, text=True).stdout)
    assert info["size"] == [5, 3] and len(info["bands"]) == 4, info["size"]
    assert info["driverShortName"] == "ENVI"
    band1_max = info["bands"][0]["computedMax"]
    assert abs(band1_max - S[:, :, 0].max()) < 1e-3, (band1_max, S[:, :, 0].max())  # gdalinfo rounds to 3 decimals
    print("GDAL:", info["driverShortName"], "size", info["size"], "bands", len(info["bands"]),
          "band 1 description", info["bands"][0].get("description"), "max", band1_max)
    print("ENVI output opens in Spectral Python and GDAL")


if __name__ == "__main__":
    sys.exit(main())
