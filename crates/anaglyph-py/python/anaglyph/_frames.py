"""Frame sequences: every frame of a clip through the same pipeline, into memory or a
Zarr v3 store that xarray, Dask and napari open directly."""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import _core
from ._core import Rig
from ._pipeline import (
    PathLike,
    Progress,
    Reconstruction,
    _captures,
    _core_options,
    _reconstruction,
    _rig,
)

logger = logging.getLogger("anaglyph")


@dataclass
class FrameReport:
    """What one frame's run did: its ``frame`` number, the ``seconds`` it took (the whole
    call, without its write), ``store_seconds`` its write took (on a thread of its own while
    the next frame is computed), ``store_wait_seconds`` the next frame (or the end of the
    run) then waited for that write, whether it was ``skipped`` (already in the store), its
    ``warnings`` and what it reused of the previous frame (``reuse``, the manifest's
    ``temporal_reuse``: ``cut``, ``narrowed_range``, ``range_fallback``,
    ``banded`` (registration's tiles searched around the previous maps), ``priors_carried``,
    ...; None when skipped)."""

    frame: int
    seconds: float
    store_seconds: float = 0.0
    store_wait_seconds: float = 0.0
    skipped: bool = False
    warnings: list[str] = field(default_factory=list)
    reuse: dict[str, Any] | None = None


@dataclass
class SequenceRun:
    """A sequence written to a Zarr ``store``: one :class:`FrameReport` per frame, in order.
    ``xarray.open_zarr(run.store)`` opens the result."""

    store: Path
    frames: list[FrameReport]


@dataclass
class _LazyFrame:
    """A frame of a folder, read when its captures are needed."""

    folder: "FrameFolder"
    number: int

    def read(self) -> dict[str, np.ndarray]:
        return self.folder[self.number]

    def files(self) -> dict[str, str]:
        return {k: os.fspath(v) for k, v in self.folder.files(self.number).items()}


class FrameFolder(Mapping[int, dict[str, np.ndarray]]):
    """The frames of a capture folder as a mapping frame number -> captures, each frame
    read (its files' samples, :func:`read_capture`) when it is asked for; see
    :func:`read_frames`. ``files(number)`` gives a frame's paths without reading them."""

    def __init__(self, rig: Rig, folder: PathLike, layout: str | None = None, frames: str = "all"):
        self.rig = rig
        self.folder = Path(folder)
        names = [c["name"] for c in rig.cameras]
        self._files = {
            number: dict(zip(names, (Path(p) for p in paths)))
            for number, paths in _core.discover_frames(rig, os.fspath(folder), layout, frames)
        }

    def files(self, number: int) -> dict[str, Path]:
        return dict(self._files[number])

    def __getitem__(self, number: int) -> dict[str, np.ndarray]:
        return {name: _core.read_capture(path) for name, path in self._files[number].items()}

    def __iter__(self):
        return iter(self._files)

    def __len__(self) -> int:
        return len(self._files)

    def __repr__(self) -> str:
        numbers = list(self._files)
        return f"FrameFolder({str(self.folder)!r}, {len(numbers)} frames, {numbers[0]} to {numbers[-1]})"


def read_frames(
    folder: PathLike, rig: Rig | str, layout: str | None = None, frames: str = "all"
) -> FrameFolder:
    """The frames of a capture folder: a folder per frame (``<frame>/<camera>.png``,
    ``layout="frame-major"``) or per camera (``<camera>/<frame>.png``, ``"camera-major"``;
    the default when there is a folder per camera), numbered by the last number in each
    name, in numerical order; ``frames`` is ``"all"``, ``"A:B"`` (both included) or one
    number. Every capture is found here, before any is read; a frame's captures are read
    when it is used (``frames[number]``), so a clip need not fit in memory. What
    ``anaglyph reconstruct --frames`` reads.

    >>> clip = anaglyph.read_frames("captures", rig)                          # doctest: +SKIP
    >>> anaglyph.reconstruct_frames(rig, clip, store="clip.zarr", whites=w)   # doctest: +SKIP
    """
    return FrameFolder(_rig(rig), folder, layout, frames)


def _numbered(frames: Any) -> list[tuple[int, Any]]:
    """``frames`` as (frame number, captures) pairs: a mapping keeps its numbers, a
    sequence is numbered from 0."""
    if isinstance(frames, (str, os.PathLike)):
        raise TypeError("frames: a folder of frames is read with anaglyph.read_frames(folder, rig)")
    if isinstance(frames, FrameFolder):
        items = [(n, _LazyFrame(frames, n)) for n in frames]
    elif isinstance(frames, Mapping):
        items = list(frames.items())
    elif isinstance(frames, Sequence):
        items = list(enumerate(frames))
    else:
        raise TypeError(
            "frames: expected a dict of frame number -> captures or a list of captures dicts, "
            f"got {type(frames).__name__}"
        )
    if not items:
        raise ValueError("frames: no frames (expected at least one)")
    numbered: list[tuple[int, Any]] = []
    for number, captures in items:
        if isinstance(number, bool) or not isinstance(number, (int, np.integer)):
            raise TypeError(f"frames: frame numbers must be integers, got {number!r}")
        numbered.append((int(number), captures))
    numbers = [n for n, _ in numbered]
    if len(set(numbers)) != len(numbers):
        raise ValueError(f"frames: frame numbers given twice in {numbers}")
    return numbered


def _check_frames(rig: Rig, numbered: list[tuple[int, Any]]) -> None:
    """Every frame has the first frame's cameras, shapes and dtypes (checked before any
    work; the core checks the first frame against the rig). The frames of a
    :class:`FrameFolder` were found whole by the core and are read one at a time."""
    if any(isinstance(c, _LazyFrame) for _, c in numbered):
        return
    first_number, first = numbered[0]
    reference = _captures(first, f"frame {first_number}")
    shapes = {name: (np.shape(a), getattr(a, "dtype", None)) for name, a in reference.items()}
    for number, captures in numbered[1:]:
        captures = _captures(captures, f"frame {number}")
        missing = sorted(set(shapes) - set(captures))
        extra = sorted(set(captures) - set(shapes))
        if missing or extra:
            raise _core.CapturesError(
                f"frame {number}: cameras {missing or extra} "
                f"({'missing' if missing else 'not in'} frame {first_number}'s)"
                f" (expected the cameras of frame {first_number}: {sorted(shapes)})"
            )
        for name, image in captures.items():
            found = (np.shape(image), getattr(image, "dtype", None))
            if found != shapes[name]:
                raise _core.RasterError(
                    f"frame {number}: camera {name}: shape {found[0]} of {found[1]} "
                    f"(expected frame {first_number}'s {shapes[name][0]} of {shapes[name][1]})"
                )


def _frame_darks(
    frame_darks: Mapping[int, Mapping[str, np.ndarray]] | None, numbers: list[int]
) -> dict[int, dict[str, Any]] | None:
    """Each frame's own dark frames, checked to cover ``numbers`` before any work."""
    if frame_darks is None:
        return None
    missing = [n for n in numbers if n not in frame_darks]
    if missing:
        raise _core.CapturesError(
            f"frame_darks: no dark frames for frame {missing[0]} (expected "
            "{frame number: {camera: image}} for every frame reconstructed)"
        )
    return {n: _captures(frame_darks[n], f"frame_darks of frame {n}") for n in numbers}


def reconstruct_frames(
    rig: Rig | str,
    frames: Mapping[int, Mapping[str, np.ndarray]] | Sequence[Mapping[str, np.ndarray]],
    store: PathLike | None = None,
    overwrite: bool = False,
    whites: Mapping[str, np.ndarray] | None = None,
    darks: Mapping[str, np.ndarray] | None = None,
    frame_darks: Mapping[int, Mapping[str, np.ndarray]] | None = None,
    calibration: Mapping[str, Any] | PathLike | None = None,
    views: Sequence[str] | None = None,
    preset: str = "default",
    output: str = "cube",
    disp_range: str | tuple[int, int] | int = "auto",
    method: str = "mccnn",
    model: PathLike | None = None,
    registration: str = "multi-baseline",
    solver: str = "exact",
    matching_image: str | None = None,
    warp_kernel: str | None = None,
    coarse_to_fine: str = "auto",
    white_reflectance: float | None = None,
    saturation: float | None = None,
    tuning: Mapping[str, Any] | None = None,
    reuse: bool | int = True,
    progress: bool | Progress = True,
) -> SequenceRun | dict[int, Reconstruction]:
    """Reconstructs every frame of a sequence, in frame order, with :func:`reconstruct`'s
    options (the white boards, dark frames and calibration hold for the whole sequence).
    ``frame_darks``: each frame's own dark frames for its captures, ``{frame number:
    {camera: image}}`` (every frame's; the white boards keep ``darks``).

    ``frames``: a dict of frame number -> captures (one image per camera, as
    :func:`reconstruct` takes), or a list of captures numbered from 0. Every frame must
    have the first frame's cameras, shapes and dtypes (checked before any work).

    With ``store`` (a path ending in ``.zarr``), each frame is written to that Zarr v3
    store as it finishes (on a thread of its own while the next frame is computed; the call
    returns once every write has ended) and the call returns a :class:`SequenceRun`
    (per-frame timings), holding no more than the frame being written in memory: ``reflectance`` ``(frame, view, y, x, wavelength)``,
    ``disparity`` and ``visibility`` ``(frame, view, y, x)``, ``registered`` ``(frame,
    view, y, x, channel)`` with ``output="registered"`` or ``"both"``, and the coordinates
    ``frame``, ``view``, ``wavelength`` (nm), ``channel``. A store of the same run is
    completed (frames already written are skipped); a store of another run is refused
    unless ``overwrite``; a folder that is not an anaglyph store is never replaced.
    Without ``store``: a dict of frame number -> :class:`Reconstruction`.

    With ``reuse`` (the default) each frame starts from what the previous frame learned
    where that is sound: the search range narrowed to the previous disparities (searched
    again in full where surfaces left it) and each view's scene prior (learned again where
    a new material appears); a cut (another scene) falls back to a frame reconstructed
    alone. ``reuse=N`` starts a new chain every N frames of the run (as each task of
    :func:`anaglyph.dask.reconstruct_frames` with ``batch=N`` does, whose bytes it then
    gives); ``False`` reconstructs every frame alone. A resumed store starts a chain at
    the first frame it computes. Each frame's manifest says what it reused
    (``temporal_reuse``).

    >>> run = anaglyph.reconstruct_frames(rig, {0: cap0, 1: cap1}, store="clip.zarr")  # doctest: +SKIP
    >>> xarray.open_zarr("clip.zarr")["reflectance"].dims                              # doctest: +SKIP
    ('frame', 'view', 'y', 'x', 'wavelength')
    """
    rig = _rig(rig)
    numbered = _numbered(frames)
    _check_frames(rig, numbered)
    own_darks = _frame_darks(frame_darks, [n for n, _ in numbered])
    options = _core_options(
        whites=whites,
        darks=darks,
        calibration=calibration,
        views=views,
        preset=preset,
        output=output,
        disp_range=disp_range,
        method=method,
        model=model,
        registration=registration,
        solver=solver,
        matching_image=matching_image,
        warp_kernel=warp_kernel,
        coarse_to_fine=coarse_to_fine,
        white_reflectance=white_reflectance,
        saturation=saturation,
        tuning=tuning,
        reuse=reuse is not False and reuse != 0,
    )
    chain = 0 if isinstance(reuse, bool) else int(reuse)
    if chain < 0:
        raise _core.SettingError(f"reuse is {reuse} (expected True, False or a chain length >= 1)")
    numbers = [n for n, _ in numbered]
    bar = None
    callback = progress if callable(progress) else None
    if progress is True:
        from tqdm.auto import tqdm  # type: ignore[import-untyped]

        bar = tqdm(total=len(numbered), desc="anaglyph", unit="frame")
    reports: list[FrameReport] = []
    results: dict[int, Reconstruction] = {}
    carry = None  # what the last frame computed hands to the next
    # The last frame's write, on a thread of its own while the next frame is computed, and
    # that frame's report.
    pending = None
    pending_report: FrameReport | None = None
    try:
        for index, (number, captures) in enumerate(numbered):
            started = time.perf_counter()
            if chain and index % chain == 0:
                carry = None
            if bar is not None:
                bar.set_postfix_str(f"frame {number}", refresh=True)
            if isinstance(captures, _LazyFrame):
                captures = captures.read()
            out = _core.reconstruct(
                rig,
                _captures(captures, f"frame {number}"),
                progress=callback,
                store=os.fspath(store) if store is not None else None,
                frame=number,
                frames=numbers,
                overwrite=overwrite and not reports,
                arrays=store is None,
                skip_done=store is not None,
                previous=carry,
                frame_darks=own_darks[number] if own_darks else None,
                background_write=store is not None,
                previous_write=pending,
                **options,
            )
            seconds = time.perf_counter() - started
            if "previous_store_seconds" in out and pending_report is not None:
                pending_report.store_seconds = float(out["previous_store_seconds"])
                pending_report.store_wait_seconds = float(out["previous_store_wait_seconds"])
                pending, pending_report = None, None
            carry = out.get("carry")  # None after a skipped frame: nothing to carry over it
            if out["skipped"]:
                reports.append(FrameReport(frame=number, seconds=seconds, skipped=True))
            else:
                for warning in out["warnings"]:
                    logger.warning("frame %d: %s", number, warning)
                reports.append(
                    FrameReport(
                        frame=number,
                        seconds=seconds,
                        warnings=list(out["warnings"]),
                        reuse=out["manifest"].get("temporal_reuse"),
                    )
                )
                if "pending_write" in out:
                    pending, pending_report = out["pending_write"], reports[-1]
                if store is None:
                    results[number] = _reconstruction(out)
            if bar is not None:
                bar.update(1)
    finally:
        # The last write ends before the call returns, also when a frame failed.
        if pending is not None:
            waiting = time.perf_counter()
            written = pending.wait()
            if pending_report is not None:
                pending_report.store_seconds = written
                pending_report.store_wait_seconds = time.perf_counter() - waiting
        if bar is not None:
            bar.close()
    if store is None:
        return results
    return SequenceRun(store=Path(store), frames=reports)

