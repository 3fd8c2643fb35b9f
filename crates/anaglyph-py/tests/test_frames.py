"""Frame sequences into a Zarr v3 store: read back with zarr-python and xarray, equal to
single-frame runs, resumed by a rerun, and bad sequences refused before any work."""

from __future__ import annotations

import numpy as np
import pytest

import anaglyph

from conftest import small_rig

SIZE = (96, 72)


@pytest.fixture(scope="module")
def clip():
    """Three frames of the (still) tabletop through the paper's rig: new noise per frame,
    the same exposures."""
    rig = small_rig("paper-2x4", SIZE[0])
    sims = [anaglyph.simulate("tabletop", rig=rig, size=SIZE, seed=0, frame=k) for k in range(3)]
    frames = {10 + s: sim.captures for s, sim in enumerate(sims)}
    return rig, frames, sims[0].whites


def bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a).tobytes()


def test_a_sequence_goes_to_a_zarr_store_that_xarray_opens(clip, tmp_path):
    zarr = pytest.importorskip("zarr")
    xr = pytest.importorskip("xarray")
    rig, frames, whites = clip
    store = tmp_path / "clip.zarr"
    run = anaglyph.reconstruct_frames(rig, frames, store=store, whites=whites, output="both", progress=False)
    assert [r.frame for r in run.frames] == [10, 11, 12]
    assert not any(r.skipped for r in run.frames)
    assert all(0 < r.store_seconds < r.seconds for r in run.frames)

    ds = xr.open_zarr(store)
    assert ds["reflectance"].dims == ("frame", "view", "y", "x", "wavelength")
    assert ds["registered"].dims == ("frame", "view", "y", "x", "channel")
    assert ds["disparity"].dims == ds["visibility"].dims == ("frame", "view", "y", "x")
    assert ds["frame"].values.tolist() == [10, 11, 12]
    assert ds["view"].values.tolist() == [c["name"] for c in rig.cameras]
    assert ds["channel"].values.tolist() == rig.channel_labels()
    np.testing.assert_array_equal(ds["wavelength"].values, rig.wavelengths)
    assert ds["wavelength"].attrs["units"] == "nm"
    assert ds["visibility"].dtype == np.uint8
    # The first frame's values are a single-frame run's, bit for bit (the later frames
    # start from what it learned).
    one = anaglyph.reconstruct(rig, frames[10], whites=whites, output="both", progress=False)
    for name in ("r0c0", "r1c2"):
        at = dict(frame=10, view=name)
        assert bits(ds["reflectance"].sel(**at).values) == bits(one[name].cube)
        assert bits(ds["registered"].sel(**at).values) == bits(one[name].registered)
        assert bits(ds["disparity"].sel(**at).values) == bits(one[name].disparity)
        assert bits(ds["visibility"].sel(**at).values) == bits(one[name].cameras_seeing)
    # zarr-python sees one chunk per frame and view (views this small are not sharded).
    group = zarr.open_group(store, mode="r")
    assert group["reflectance"].chunks == (1, 1, SIZE[1], SIZE[0], len(rig.wavelengths))
    assert group["reflectance"].shards is None
    assert group.attrs["anaglyph"]["layout"]["frames"] == [10, 11, 12]

    # A rerun of the same run finds every frame written; another run is refused.
    again = anaglyph.reconstruct_frames(rig, frames, store=store, whites=whites, output="both", progress=False)
    assert all(r.skipped for r in again.frames)
    with pytest.raises(anaglyph.OutputConflictError, match="another run"):
        anaglyph.reconstruct_frames(rig, frames, store=store, whites=whites, progress=False)
    assert xr.open_zarr(store)["frame_done"].values.tolist() == [1, 1, 1]


def test_frames_reuse_what_the_previous_frame_learned(clip):
    rig, frames, whites = clip
    reused = anaglyph.reconstruct_frames(rig, frames, whites=whites, progress=False)
    first, second = (reused[k].manifest["temporal_reuse"] for k in (10, 11))
    assert first["previous"] is False and first["priors_learned"] == 8
    assert second["previous"] is True and second["cut"] is False
    assert second["correlation"] > 0.9
    assert second["priors_carried"] + second["priors_learned"] == 8
    assert second["narrowed_range"] is not None or second["range_fallback"] is False
    # Registration searched each tile around the previous frame's maps.
    assert second["banded"]["tiles"] > 0 and first["banded"] is None
    # The same scene again: the reused frame's cube differs from the frame alone no more
    # than two frames alone differ (their noise).
    alone = anaglyph.reconstruct_frames(rig, frames, whites=whites, reuse=False, progress=False)
    one = anaglyph.reconstruct(rig, frames[11], whites=whites, progress=False)
    assert bits(alone[11]["r0c0"].cube) == bits(one["r0c0"].cube)
    assert "temporal_reuse" not in one.manifest
    def rms(a: np.ndarray, b: np.ndarray) -> float:
        known = np.isfinite(a) & np.isfinite(b)
        assert known.mean() > 0.8
        return float(np.sqrt(np.mean((a[known] - b[known]) ** 2)))

    scatter = rms(alone[10]["r0c0"].cube, alone[11]["r0c0"].cube)
    assert rms(reused[11]["r0c0"].cube, one["r0c0"].cube) < 1.2 * scatter
    # A still scene: most pixels keep their spectra.
    assert second["reused_pixels"] > 0.5 * 8 * SIZE[0] * SIZE[1]
    # Chains of one frame reuse nothing.
    chained = anaglyph.reconstruct_frames(rig, frames, whites=whites, reuse=1, progress=False)
    assert bits(chained[11]["r0c0"].cube) == bits(one["r0c0"].cube)
    with pytest.raises(anaglyph.SettingError, match="reuse"):
        anaglyph.reconstruct_frames(rig, frames, whites=whites, reuse=-2, progress=False)


def test_bad_sequences_are_refused_before_any_work(clip, tmp_path):
    rig, frames, whites = clip
    missing = dict(frames)
    missing[11] = {k: v for k, v in frames[11].items() if k != "r0c3"}
    with pytest.raises(anaglyph.CapturesError, match="frame 11.*r0c3"):
        anaglyph.reconstruct_frames(rig, missing, whites=whites, progress=False)
    smaller = dict(frames)
    smaller[12] = {k: v[:-1] for k, v in frames[12].items()}
    with pytest.raises(anaglyph.RasterError, match="frame 12"):
        anaglyph.reconstruct_frames(rig, smaller, whites=whites, progress=False)
    with pytest.raises(ValueError, match="no frames"):
        anaglyph.reconstruct_frames(rig, {}, whites=whites, progress=False)
    with pytest.raises(TypeError, match="frame numbers"):
        anaglyph.reconstruct_frames(rig, {"a": frames[10]}, whites=whites, progress=False)
    a_file = tmp_path / "notes.zarr"
    a_file.write_text("mine")
    with pytest.raises(anaglyph.OutputConflictError, match="a file"):
        anaglyph.reconstruct_frames(rig, frames, store=a_file, whites=whites, overwrite=True, progress=False)
    assert a_file.read_text() == "mine"
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "data.csv").write_text("1,2")
    with pytest.raises(anaglyph.OutputConflictError, match="not an anaglyph"):
        anaglyph.reconstruct_frames(rig, frames, store=foreign, whites=whites, overwrite=True, progress=False)
    assert (foreign / "data.csv").read_text() == "1,2"


def test_without_a_store_every_frame_comes_back_in_memory(clip):
    rig, frames, whites = clip
    two = {k: frames[k] for k in (10, 12)}
    out = anaglyph.reconstruct_frames(rig, two, whites=whites, views=["r0c1"], progress=False)
    assert sorted(out) == [10, 12]
    assert out[12]["r0c1"].cube.shape == (SIZE[1], SIZE[0], len(rig.wavelengths))
    assert list(out[10].views) == ["r0c1"]


def test_a_folder_of_frames_gives_the_clis_store(cli, tmp_path):
    zarr = pytest.importorskip("zarr")
    from conftest import run_cli

    cameras = [c["name"] for c in anaglyph.Rig.preset("paper-2x4").cameras]
    for seed in range(2):
        run_cli(cli, "simulate", "--scene", "tabletop", "--size", "96x72", "--seed", str(seed), "--out", str(tmp_path / f"sim{seed}"))
        for cam in cameras:
            target = tmp_path / "clip" / cam / f"frame_{seed}.png"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes((tmp_path / f"sim{seed}" / "captures" / f"{cam}.png").read_bytes())
    rig = anaglyph.Rig.load(tmp_path / "sim0" / "rig.toml")
    clip = anaglyph.read_frames(tmp_path / "clip", rig)
    assert list(clip) == [0, 1] and len(clip) == 2
    frame = clip[1]
    assert frame["r0c0"].dtype == np.uint16
    np.testing.assert_array_equal(
        frame["r0c0"].astype(np.float32) / 65535, anaglyph.read_image(clip.files(1)["r0c0"])
    )
    whites = {cam: anaglyph.read_capture(tmp_path / "sim0" / "white" / f"{cam}.png") for cam in cameras}
    anaglyph.reconstruct_frames(rig, clip, store=tmp_path / "py.zarr", whites=whites, disp_range=(0, 12), progress=False)
    run_cli(
        cli, "reconstruct", "--rig", str(tmp_path / "sim0" / "rig.toml"), "--captures", str(tmp_path / "clip"),
        "--white", str(tmp_path / "sim0" / "white"), "--frames", "all", "--disp-range", "0:12",
        "--out", str(tmp_path / "cli.zarr"),
    )
    py, cli_store = zarr.open_group(tmp_path / "py.zarr", mode="r"), zarr.open_group(tmp_path / "cli.zarr", mode="r")
    for name in ("reflectance", "disparity", "visibility"):
        assert py[name][...].tobytes() == cli_store[name][...].tobytes(), name
    with pytest.raises(anaglyph.CapturesError, match="frame 1"):
        (tmp_path / "clip" / "r1c1" / "frame_1.png").unlink()
        anaglyph.read_frames(tmp_path / "clip", rig)


def test_simulated_frames_move_and_keep_the_exposures():
    rig = small_rig("paper-2x4", 64)
    first = anaglyph.simulate("tabletop-moving", rig=rig, size=(64, 48), seed=3)
    again = anaglyph.simulate("tabletop-moving", rig=rig, size=(64, 48), seed=3, frame=0)
    later = anaglyph.simulate("tabletop-moving", rig=rig, size=(64, 48), seed=3, frame=5)
    assert bits(first.captures["r0c0"]) == bits(again.captures["r0c0"])
    assert first.exposures == later.exposures
    assert bits(first.captures["r0c0"]) != bits(later.captures["r0c0"])
    moved = np.abs(first.disparity["r0c0"] - later.disparity["r0c0"]) > 0.01
    assert 0.02 < np.mean(moved) < 0.9


def test_each_frame_may_bring_its_own_dark_frames():
    rig = small_rig("paper-2x4", 64)
    sims = [anaglyph.simulate("tabletop", rig=rig, size=(64, 48), seed=0, frame=k, dark=(0.05, 0.01)) for k in range(2)]
    frames = {k: sim.captures for k, sim in enumerate(sims)}
    master = sims[0].darks
    options = dict(whites=sims[0].whites, disp_range=(0, 8), reuse=False, progress=False)
    one_set = anaglyph.reconstruct_frames(rig, frames, darks=master, **options)
    per_frame = anaglyph.reconstruct_frames(rig, frames, darks=master, frame_darks={0: master, 1: master}, **options)
    for k in (0, 1):
        assert bits(one_set[k]["r0c0"].cube) == bits(per_frame[k]["r0c0"].cube)
    # Frame 1's own darks (another camera's pattern) change frame 1 alone.
    names = [c["name"] for c in rig.cameras]
    swapped = {name: master[names[(i + 1) % len(names)]] for i, name in enumerate(names)}
    changed = anaglyph.reconstruct_frames(rig, frames, darks=master, frame_darks={0: master, 1: swapped}, **options)
    assert bits(changed[0]["r0c0"].cube) == bits(one_set[0]["r0c0"].cube)
    assert bits(changed[1]["r0c0"].cube) != bits(one_set[1]["r0c0"].cube)
    with pytest.raises(anaglyph.CapturesError, match="frame 1"):
        anaglyph.reconstruct_frames(rig, frames, darks=master, frame_darks={0: master}, **options)
