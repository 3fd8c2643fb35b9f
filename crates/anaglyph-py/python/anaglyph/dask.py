"""Frame-sharded runs on a Dask cluster (``distributed``): batches of consecutive frames
on the workers, each writing its own frames into one Zarr store.

    from distributed import Client, LocalCluster
    import anaglyph.dask

    client = Client(LocalCluster(n_workers=2, threads_per_worker=1))
    run = anaglyph.dask.reconstruct_frames(rig, frames, "clip.zarr", client=client, whites=whites)

The store's template (every array's metadata, the coordinates) is written by the caller
before any task; each task reconstructs a batch of frames and writes their chunks or shards
(one object per frame and view, so tasks never share one) and returns only a small report. A task that
fails or whose worker is lost is run again by the scheduler and writes the same objects
(frames already marked done are skipped). Each worker's reconstruction uses as many
threads as the worker has (``anaglyph.set_num_threads``), so workers × threads never
oversubscribe the cores. ``docs/cluster.md`` runs it on Slurm through ``dask-jobqueue``.
"""

from __future__ import annotations

import functools
import inspect
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import _core
from ._core import Rig
from ._frames import FrameReport, SequenceRun, _check_frames, _frame_darks, _LazyFrame, _numbered
from ._pipeline import PathLike, _captures, _core_options, _rig


def _read(captures: dict[str, Any]) -> dict[str, Any]:
    """A frame's captures, read where they travelled as paths (a folder's frames: the
    worker reads them from the shared filesystem)."""
    return {name: _core.read_capture(v) if isinstance(v, str) else v for name, v in captures.items()}


def _run_batch(
    batch: list[tuple[int, dict[str, Any], dict[str, Any] | None]],
    rig: Rig,
    store: str,
    numbers: list[int],
    options: dict[str, Any],
) -> list[dict[str, Any]]:
    """Reconstructs and writes one batch of frames on a worker; returns their reports."""
    import time

    from distributed import get_worker

    try:
        _core.set_num_threads(max(1, int(get_worker().state.nthreads)))
    except ValueError:  # not on a worker (a synchronous scheduler): keep the default
        pass
    reports: list[dict[str, Any]] = []
    # Temporal reuse chains the batch's frames from its first, so a batch that a lost
    # worker left half written is computed again from its first frame (rewriting the
    # same bytes), not resumed in the middle of its chain.
    recompute = False
    if options.get("reuse", True):
        probe = _core.reconstruct(
            rig,
            _read(batch[0][1]),
            store=store,
            frame=batch[0][0],
            frames=numbers,
            create_only=True,
            **options,
        )
        done = dict(zip(numbers, probe["frames_done"]))
        recompute = not all(done[item[0]] for item in batch)
    carry = None
    # Each frame's write runs on a thread of its own while the next frame is computed; the
    # task returns once the last one has ended.
    pending = None
    try:
        for number, captures, darks in batch:
            started = time.perf_counter()
            out = _core.reconstruct(
                rig,
                _read(captures),
                frame_darks=darks,
                store=store,
                frame=number,
                frames=numbers,
                arrays=False,
                skip_done=not recompute,
                previous=carry,
                background_write=True,
                previous_write=pending,
                **options,
            )
            carry = out.get("carry")
            if "previous_store_seconds" in out:
                reports[-1]["store_seconds"] = float(out["previous_store_seconds"])
                pending = None
            reports.append(
                {
                    "frame": number,
                    "seconds": time.perf_counter() - started,
                    "store_seconds": 0.0,
                    "skipped": bool(out["skipped"]),
                    "warnings": list(out.get("warnings", [])),
                    "reuse": out.get("manifest", {}).get("temporal_reuse"),
                }
            )
            if "pending_write" in out:
                pending = out["pending_write"]
    finally:
        if pending is not None:
            written = pending.wait()
            if reports:
                reports[-1]["store_seconds"] = written
    return reports


def reconstruct_frames(
    rig: Rig | str,
    frames: Mapping[int, Mapping[str, np.ndarray]] | Sequence[Mapping[str, np.ndarray]],
    store: PathLike,
    client: Any = None,
    batch: int = 4,
    overwrite: bool = False,
    progress: bool = True,
    **options: Any,
) -> SequenceRun:
    """:func:`anaglyph.reconstruct_frames` into ``store`` on a Dask cluster: batches of
    ``batch`` consecutive frames as tasks of ``client`` (default: the current client).
    ``options`` are :func:`anaglyph.reconstruct`'s (``whites``, ``output``, ``preset``,
    ...), ``reuse`` and ``frame_darks`` (each frame's darks travel with its task). ``store`` must be on a filesystem every worker sees. Returns the
    per-frame reports in frame order. Temporal reuse chains the frames of each batch, so
    the bytes of the store are those of a serial run with ``reuse=batch`` (or of any run
    with ``reuse=False``); a task rerun after a lost worker writes the same bytes.
    """
    from distributed import get_client, wait
    from distributed import progress as dask_progress

    if batch < 1:
        raise _core.SettingError(f"batch is {batch} (expected at least 1 frame per task)")
    rig = _rig(rig)
    numbered = _numbered(frames)
    _check_frames(rig, numbered)
    client = client if client is not None else get_client()
    workers = client.scheduler_info().get("workers", {})
    if not workers:
        raise _core.SettingError(
            "client: a Dask client with no workers (expected a cluster with at least one worker)"
        )
    own_darks = _frame_darks(options.pop("frame_darks", None), [n for n, _ in numbered])
    unknown = sorted(set(options) - set(inspect.signature(_core_options).parameters))
    if unknown:
        raise TypeError(f"reconstruct_frames: unknown options {unknown}")
    core_options = _core_options(**options)
    path = os.fspath(Path(store).absolute())
    numbers = [n for n, _ in numbered]
    # The template, before any task: made (or a store of the same run reopened) from the
    # first frame's captures, with no compute.
    first_number, first = numbered[0]
    if isinstance(first, _LazyFrame):
        first = first.read()
    _core.reconstruct(
        rig,
        _captures(first, f"frame {first_number}"),
        store=path,
        frame=first_number,
        frames=numbers,
        overwrite=overwrite,
        create_only=True,
        **core_options,
    )
    def shipped(number: int, captures: Any) -> dict[str, Any]:
        if isinstance(captures, _LazyFrame):
            return captures.files()
        return _captures(captures, f"frame {number}")

    batches = [
        [(n, shipped(n, c), own_darks[n] if own_darks else None) for n, c in numbered[i : i + batch]]
        for i in range(0, len(numbered), batch)
    ]
    # The run's settings travel with the function, each batch's captures with its task
    # (not scattered: data scattered to a worker that dies is lost with it, while a task's
    # own arguments are sent again when the scheduler reruns it).
    run_batch = functools.partial(
        _run_batch, rig=rig, store=path, numbers=numbers, options=core_options
    )
    futures = client.map(run_batch, batches, pure=False)
    if progress:
        dask_progress(futures)
    wait(futures)
    reports = [FrameReport(**r) for batch_reports in client.gather(futures) for r in batch_reports]
    return SequenceRun(store=Path(store), frames=reports)
