"""Frame-sharded runs on a 2-worker LocalCluster: the store's bytes are a serial run's,
and a client without workers is refused."""

from __future__ import annotations

import os
import pickle
import signal
import threading
import time

import numpy as np
import pytest

import anaglyph

from conftest import small_rig

distributed = pytest.importorskip("distributed")
zarr = pytest.importorskip("zarr")

SIZE = (96, 72)


@pytest.fixture(scope="module")
def clip():
    """Four frames of the tabletop (different noise) through the paper's rig."""
    rig = small_rig("paper-2x4", SIZE[0])
    sims = [anaglyph.simulate("tabletop", rig=rig, size=SIZE, seed=s) for s in range(4)]
    return rig, {s: sim.captures for s, sim in enumerate(sims)}, sims[0].whites


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    )
    with distributed.Client(cluster) as client:
        yield client
    cluster.close()


def arrays(store) -> dict[str, np.ndarray]:
    group = zarr.open_group(store, mode="r")
    return {name: group[name][...] for name in ("reflectance", "disparity", "visibility", "frame_done")}


def test_a_rig_survives_pickling(clip):
    rig, _, _ = clip
    again = pickle.loads(pickle.dumps(rig))
    assert again.to_toml() == rig.to_toml()
    np.testing.assert_array_equal(again.sensing_matrix()[0], rig.sensing_matrix()[0])


def test_the_cluster_writes_the_bytes_of_a_serial_run(clip, client, tmp_path):
    import anaglyph.dask

    rig, frames, whites = clip
    serial = tmp_path / "serial.zarr"
    # Each task chains its batch's frames: a serial run of chains of 2.
    anaglyph.reconstruct_frames(rig, frames, store=serial, whites=whites, reuse=2, progress=False)
    sharded = tmp_path / "sharded.zarr"
    run = anaglyph.dask.reconstruct_frames(
        rig, frames, sharded, client=client, batch=2, whites=whites, progress=False
    )
    assert [r.frame for r in run.frames] == [0, 1, 2, 3]
    assert not any(r.skipped for r in run.frames)
    expected, got = arrays(serial), arrays(sharded)
    for name in expected:
        assert expected[name].tobytes() == got[name].tobytes(), name
    # Run again, every frame is found written.
    again = anaglyph.dask.reconstruct_frames(rig, frames, sharded, client=client, batch=2, whites=whites, progress=False)
    assert all(r.skipped for r in again.frames)


def test_a_worker_killed_mid_run_ends_with_the_same_bytes(clip, client, tmp_path):
    import anaglyph.dask

    rig, frames, whites = clip
    serial = tmp_path / "serial.zarr"
    anaglyph.reconstruct_frames(rig, frames, store=serial, whites=whites, reuse=2, progress=False)
    store = tmp_path / "killed.zarr"
    outcome: dict[str, object] = {}

    def run() -> None:
        try:
            outcome["run"] = anaglyph.dask.reconstruct_frames(
                rig, frames, store, client=client, batch=2, whites=whites, progress=False
            )
        except BaseException as e:  # surfaced by the assertion below
            outcome["error"] = e

    thread = threading.Thread(target=run)
    thread.start()
    # Once the first frame is written, kill one worker's process outright (SIGKILL):
    # its nanny starts a new one and the scheduler runs the lost batch again, from its
    # first frame (the batch's frames chain their temporal reuse).
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        done = (store / "frame_done").exists() and zarr.open_group(store, mode="r")["frame_done"][...].sum()
        if done:
            break
        time.sleep(0.05)
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    os.kill(victim, signal.SIGKILL)
    thread.join(timeout=300)
    assert "error" not in outcome, outcome.get("error")
    assert [r.frame for r in outcome["run"].frames] == [0, 1, 2, 3]
    expected, got = arrays(serial), arrays(store)
    for name in expected:
        assert expected[name].tobytes() == got[name].tobytes(), name


def test_bad_runs_are_refused_before_any_task(clip, client, tmp_path):
    import anaglyph.dask

    rig, frames, whites = clip
    with pytest.raises(anaglyph.SettingError, match="batch"):
        anaglyph.dask.reconstruct_frames(rig, frames, tmp_path / "a.zarr", client=client, batch=0, whites=whites)
    with pytest.raises(TypeError, match="unknown options"):
        anaglyph.dask.reconstruct_frames(rig, frames, tmp_path / "a.zarr", client=client, whites=whites, colour="red")
    a_file = tmp_path / "notes.zarr"
    a_file.write_text("mine")
    with pytest.raises(anaglyph.OutputConflictError, match="a file"):
        anaglyph.dask.reconstruct_frames(rig, frames, a_file, client=client, whites=whites, progress=False)
    assert a_file.read_text() == "mine"
    empty = distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0")
    with distributed.Client(empty, set_as_default=False) as nobody:
        with pytest.raises(anaglyph.SettingError, match="no workers"):
            anaglyph.dask.reconstruct_frames(rig, frames, tmp_path / "b.zarr", client=nobody, whites=whites)
    empty.close()
    assert not (tmp_path / "a.zarr").exists() and not (tmp_path / "b.zarr").exists()


def test_workers_read_the_frames_of_a_folder_themselves(cli, client, tmp_path):
    import anaglyph.dask
    from conftest import run_cli

    for seed in range(2):
        run_cli(cli, "simulate", "--scene", "tabletop", "--size", "96x72", "--seed", str(seed), "--out", str(tmp_path / f"sim{seed}"))
        (tmp_path / "clip" / f"{seed:04}").mkdir(parents=True)
        for png in (tmp_path / f"sim{seed}" / "captures").iterdir():
            (tmp_path / "clip" / f"{seed:04}" / png.name).write_bytes(png.read_bytes())
    rig = anaglyph.Rig.load(tmp_path / "sim0" / "rig.toml")
    clip = anaglyph.read_frames(tmp_path / "clip", rig)
    whites = {c["name"]: anaglyph.read_capture(tmp_path / "sim0" / "white" / f"{c['name']}.png") for c in rig.cameras}
    serial = tmp_path / "serial.zarr"
    anaglyph.reconstruct_frames(rig, clip, store=serial, whites=whites, reuse=1, progress=False)
    sharded = tmp_path / "sharded.zarr"
    anaglyph.dask.reconstruct_frames(rig, clip, sharded, client=client, batch=1, whites=whites, progress=False)
    expected, got = arrays(serial), arrays(sharded)
    for name in expected:
        assert expected[name].tobytes() == got[name].tobytes(), name


def test_frames_own_dark_frames_travel_with_their_tasks(clip, client, tmp_path):
    import anaglyph.dask

    rig, frames, whites = clip
    # Frame 2's captures lose a dark level of 2 % of full scale; the others none.
    level = {k: np.full_like(frames[k]["r0c0"], 1311 if k == 2 else 0) for k in frames}
    frame_darks = {k: {c["name"]: level[k] for c in rig.cameras} for k in frames}
    serial = tmp_path / "serial.zarr"
    anaglyph.reconstruct_frames(
        rig, frames, store=serial, whites=whites, frame_darks=frame_darks, reuse=2, progress=False
    )
    sharded = tmp_path / "sharded.zarr"
    anaglyph.dask.reconstruct_frames(
        rig, frames, sharded, client=client, batch=2, whites=whites, frame_darks=frame_darks, progress=False
    )
    expected, got = arrays(serial), arrays(sharded)
    for name in expected:
        assert expected[name].tobytes() == got[name].tobytes(), name
    plain = tmp_path / "plain.zarr"
    anaglyph.reconstruct_frames(rig, frames, store=plain, whites=whites, reuse=2, progress=False)
    cubes, darkened = arrays(plain)["reflectance"], expected["reflectance"]
    assert cubes[:2].tobytes() == darkened[:2].tobytes()
    assert cubes[2].tobytes() != darkened[2].tobytes()
