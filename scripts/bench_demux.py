#!/usr/bin/env python3
"""Wall time of `anaglyph demux` (exact bounded solution) against numpy's unconstrained
closed form S = P (CᵀC + λDᵀD)⁻¹Cᵀ on the same 2-megapixel, 24-channel .npy, load and save
included. Needs numpy (`pip install numpy`) and a release build (`cargo build --release`).

    python3 scripts/bench_demux.py [--pixels 2000000] [--repeat 3]

C comes from the paper rig (`anaglyph rig show --export-c`, 24 × 52 with out-of-band
knots); P renders mixtures of the vendored CIE 2017 TCS reflectances through C with
Gaussian noise (σ = 0.003), so a realistic share of pixels touches s >= 0.
"""
import argparse, os, subprocess, sys, tempfile, time
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "anaglyph")
RIG_FILTERS = ["gel_deep_red", "gel_salmon", "gel_magenta", "gel_lavender",
               "gel_violet", "gel_teal", "gel_yellow_green", "gel_emerald"]


def write_rig(path):
    cams = "".join(f"\n[[camera]]\nrow = {i // 4}\ncol = {i % 4}\nfilter = \"builtin:{f}\"\n"
                   for i, f in enumerate(RIG_FILTERS))
    with open(path, "w") as fh:
        fh.write("name = \"paper-2x4\"\nrows = 2\ncols = 4\nfocal_length_px = 1800.0\n"
                 "sensor = \"builtin:canon_eos_5d_mark_ii\"\nilluminant = \"builtin:cie_a\"\n"
                 "[baseline_mm]\nhorizontal = 30.0\nvertical = 50.0\n" + cams)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pixels", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="anaglyph-bench-")
    rig, c_path = os.path.join(tmp, "rig.toml"), os.path.join(tmp, "C.npy")
    write_rig(rig)
    subprocess.run([BIN, "rig", "show", rig, "--plot", os.path.join(tmp, "r.svg"), "--export-c", c_path],
                   check=True, capture_output=True)
    C = np.load(c_path)
    rows, n = C.shape
    knots = 450.0 + 8.0 * (np.arange(n) - 9)  # 378 ... 786 nm (9 knots below 450)
    table = np.genfromtxt(os.path.join(ROOT, "data/spectra/reflectances/tcs_cfi2017_99.csv"),
                          delimiter=",", skip_header=1)
    wl, refl = table[:, 0], table[:, 1:]
    basis = np.stack([np.interp(knots, wl, refl[:, j]) for j in range(refl.shape[1])])
    rng = np.random.default_rng(1)
    w = rng.dirichlet(np.ones(3), size=args.pixels)
    idx = rng.integers(0, basis.shape[0], size=(args.pixels, 3))
    S = np.einsum("pk,pkn->pn", w, basis[idx])
    P = (S @ C.T + rng.normal(0, 0.003, size=(args.pixels, rows))).astype(np.float32)
    p_path = os.path.join(tmp, "P.npy")
    np.save(p_path, P)
    del S, P

    def fresh(name):
        # Both tools write a new file each run: replacing an existing file makes ext4 flush
        # it to disk first, which would measure the disk rather than the tools.
        path = os.path.join(tmp, name)
        if os.path.exists(path):
            os.remove(path)
        subprocess.run(["sync"], check=True)
        return path

    def ours():
        fresh("S_ours.npy")
        t = time.perf_counter()
        out = subprocess.run([BIN, "demux", "--sensing", c_path, "--measurements", p_path,
                              "--out", os.path.join(tmp, "S_ours.npy")], check=True, capture_output=True, text=True)
        return time.perf_counter() - t, out.stdout.strip()

    def numpy_closed_form(lam=0.01):
        out = fresh("S_numpy.npy")
        t = time.perf_counter()
        P = np.load(p_path)
        D = np.diff(np.eye(n), axis=0)
        A = np.linalg.solve(C.T @ C + lam * D.T @ D, C.T)
        S = (P @ A.T.astype(np.float32))
        np.save(out, S)
        return time.perf_counter() - t

    ours_times, numpy_times, log = [], [], ""
    for _ in range(args.repeat):
        s, log = ours()
        ours_times.append(s)
        numpy_times.append(numpy_closed_form())
    print(f"{args.pixels} pixels x {rows} measurements -> {n} unknowns")
    print(f"anaglyph demux (exact, bounded): best {min(ours_times):.3f} s, median {sorted(ours_times)[len(ours_times)//2]:.3f} s")
    print(f"numpy closed form (unbounded):   best {min(numpy_times):.3f} s, median {sorted(numpy_times)[len(numpy_times)//2]:.3f} s")
    print("anaglyph says:", log)
    a, b = np.load(os.path.join(tmp, "S_ours.npy")), np.load(os.path.join(tmp, "S_numpy.npy"))
    free = (b >= 0).all(axis=1)
    print(f"pixels whose unconstrained solution is non-negative: {free.mean():.1%}; "
          f"max |ours - numpy| there: {np.abs(a[free] - b[free]).max():.2e}")


if __name__ == "__main__":
    sys.exit(main())
