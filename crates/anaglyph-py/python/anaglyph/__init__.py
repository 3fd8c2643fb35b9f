"""anaglyph: multispectral light fields from a camera array behind colour filters.

The Rust core's API from Python, numpy in and out::

    import anaglyph
    sim = anaglyph.simulate("tabletop", rig="paper-2x4", size=(160, 120))
    rec = anaglyph.reconstruct(sim.rig, sim.captures, whites=sim.whites)
    cube = rec["r0c0"].cube                 # float32 (H, W, bands), bands last
    rec.wavelengths                         # band centres, nm

Images are numpy arrays ``(H, W)`` or ``(H, W, 3)`` of ``uint8`` / ``uint16`` (scaled by
their full scale, as the CLI reads 8- and 16-bit files) or ``float32`` / ``float64``
(linear, 1.0 = full scale). Every compute call releases the GIL and runs on the threads
:func:`set_num_threads` chose. Errors are :class:`AnaglyphError` subclasses, one per
cause, that also derive from the matching builtin (``ValueError``, ``FileNotFoundError``,
``OSError``, ``MemoryError``, ``ArithmeticError``).
"""

from __future__ import annotations

from . import _core
from ._core import (
    Rig,
    __version__,
    demux,
    find_board,
    get_num_threads,
    read_capture,
    read_envi,
    read_image,
    read_pfm,
    select_filters,
    set_num_threads,
    write_envi,
    write_pfm,
)
from ._frames import FrameFolder, FrameReport, SequenceRun, read_frames, reconstruct_frames
from ._pipeline import Reconstruction, Simulation, View, calibrate, match, reconstruct, simulate

# One exception class per cause of the core (made from its list of causes at import).
_ERRORS = {name: cls for name, cls in vars(_core).items() if name.endswith("Error")}
globals().update(_ERRORS)

#: The spellings every named option accepts (solver, method, preset, ...).
CHOICES: dict[str, list[str]] = _core.choices()

__all__ = [
    "CHOICES",
    "FrameFolder",
    "FrameReport",
    "Reconstruction",
    "Rig",
    "SequenceRun",
    "Simulation",
    "View",
    "__version__",
    "calibrate",
    "demux",
    "find_board",
    "get_num_threads",
    "match",
    "read_capture",
    "read_envi",
    "read_frames",
    "read_image",
    "read_pfm",
    "reconstruct",
    "reconstruct_frames",
    "select_filters",
    "set_num_threads",
    "simulate",
    "write_envi",
    "write_pfm",
    *sorted(_ERRORS),
]
