# Types of the compiled module anaglyph._core, checked against it in CI with
# `python -m mypy.stubtest anaglyph._core` (.ci/run).
import os
from collections.abc import Callable
from typing import Any, final

import numpy as np
import numpy.typing as npt

__version__: str
__all__ = [
    "__version__",
    "AnaglyphError",
    "IoError",
    "ParseError",
    "BadFieldError",
    "UnsupportedFormatError",
    "FileSizeError",
    "MissingFileError",
    "NonFiniteError",
    "NotFoundError",
    "RigLayoutError",
    "CapturesError",
    "CalibrationError",
    "RasterError",
    "DisparityRangeError",
    "CurveError",
    "SceneError",
    "SettingError",
    "OutputConflictError",
    "ProbeOutsideError",
    "UnusableError",
    "DecodeError",
    "OutputError",
    "CurveNotCoveringError",
    "ShapeError",
    "TooLargeError",
    "SingularNormalMatrixError",
    "OutOfRangeError",
    "StageDependencyError",
    "LinearAlgebraError",
    "NoConvergenceError",
    "CancelledError",
    "InternalError",
    "Rig",
    "FrameCarry",
    "PendingWrite",
    "choices",
    "set_num_threads",
    "get_num_threads",
    "_panic_for_tests",
    "select_filters",
    "demux",
    "match_pair_arrays",
    "simulate",
    "calibrate",
    "find_board",
    "reconstruct",
    "read_capture",
    "discover_frames",
    "read_envi",
    "write_envi",
    "read_pfm",
    "write_pfm",
    "read_image",
]

_Path = str | os.PathLike[str]
_Image = npt.NDArray[Any]

class AnaglyphError(Exception): ...
class IoError(AnaglyphError, OSError): ...
class ParseError(AnaglyphError, ValueError): ...
class BadFieldError(AnaglyphError, ValueError): ...
class UnsupportedFormatError(AnaglyphError, ValueError): ...
class FileSizeError(AnaglyphError, ValueError): ...
class MissingFileError(AnaglyphError, FileNotFoundError): ...
class NonFiniteError(AnaglyphError, ValueError): ...
class NotFoundError(AnaglyphError, ValueError): ...
class RigLayoutError(AnaglyphError, ValueError): ...
class CapturesError(AnaglyphError, ValueError): ...
class CalibrationError(AnaglyphError, ValueError): ...
class RasterError(AnaglyphError, ValueError): ...
class DisparityRangeError(AnaglyphError, ValueError): ...
class CurveError(AnaglyphError, ValueError): ...
class SceneError(AnaglyphError, ValueError): ...
class SettingError(AnaglyphError, ValueError): ...
class OutputConflictError(AnaglyphError, ValueError): ...
class ProbeOutsideError(AnaglyphError, ValueError): ...
class UnusableError(AnaglyphError, ValueError): ...
class DecodeError(AnaglyphError, ValueError): ...
class OutputError(AnaglyphError, OSError): ...
class CurveNotCoveringError(AnaglyphError, ValueError): ...
class ShapeError(AnaglyphError, ValueError): ...
class TooLargeError(AnaglyphError, MemoryError): ...
class SingularNormalMatrixError(AnaglyphError, ArithmeticError): ...
class OutOfRangeError(AnaglyphError, ValueError): ...
class StageDependencyError(AnaglyphError, ValueError): ...
class LinearAlgebraError(AnaglyphError, ArithmeticError): ...
class NoConvergenceError(AnaglyphError, ArithmeticError): ...
class CancelledError(AnaglyphError, KeyboardInterrupt): ...  # type: ignore[misc]
class InternalError(AnaglyphError, RuntimeError): ...

@final
class Rig:
    @staticmethod
    def load(path: _Path) -> Rig: ...
    @staticmethod
    def from_toml(text: str, base_dir: _Path | None = None) -> Rig: ...
    @staticmethod
    def preset(name: str) -> Rig: ...
    def __reduce__(self) -> tuple[Any, tuple[str, str]]: ...
    def to_toml(self) -> str: ...
    @property
    def name(self) -> str: ...
    @property
    def cameras(self) -> list[dict[str, Any]]: ...
    @property
    def wavelengths(self) -> npt.NDArray[np.float64]: ...
    def channel_labels(self) -> list[str]: ...
    def sensing_matrix(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    @property
    def condition_number(self) -> float: ...

def choices() -> dict[str, list[str]]: ...
def set_num_threads(n: int | None = None) -> None: ...
def get_num_threads() -> int: ...
def _panic_for_tests() -> None: ...
def select_filters(
    count: int,
    sensor: str = "builtin:canon_eos_5d_mark_ii",
    illuminant: str | None = "builtin:cie_a",
    criterion: str = "condition",
    candidates: list[str] | None = None,
    lam: float = 0.01,
    full_well: float = 10000.0,
    read_noise: float = 5.0,
    keep: int = 5,
    out_of_band: str = "extend",
) -> list[dict[str, Any]]: ...
def demux(
    p: npt.NDArray[np.floating[Any]],
    c: npt.NDArray[np.floating[Any]],
    lam: float = 0.01,
    solver: str = "exact",
    mask: npt.NDArray[np.bool_] | None = None,
    tolerance: float = 1e-10,
) -> npt.NDArray[np.floating[Any]]: ...
def match_pair_arrays(
    left: _Image,
    right: _Image,
    disp_min: int,
    disp_max: int,
    method: str = "mccnn",
    contrast: str = "auto",
    channel: str = "luminance",
    model: _Path | None = None,
) -> tuple[npt.NDArray[np.float32], dict[str, Any]]: ...
def simulate(
    scene: str,
    rig: Rig,
    width: int,
    height: int,
    seed: int = 0,
    noise: bool = True,
    supersampling: int = 2,
    vignetting: float = 0.0,
    dark: tuple[float, float] | None = None,
    frame: int = 0,
) -> dict[str, Any]: ...
def calibrate(
    boards: dict[str, _Image],
    rig: Rig,
    pattern: tuple[int, int],
    reference: str | None = None,
    model: str = "homography",
) -> dict[str, dict[str, Any]]: ...
def find_board(image: _Image, pattern: tuple[int, int]) -> npt.NDArray[np.float64]: ...
def reconstruct(
    rig: Rig,
    captures: dict[str, _Image],
    whites: dict[str, _Image] | None = None,
    darks: dict[str, _Image] | None = None,
    calibration: dict[str, Any] | str | None = None,
    views: list[str] | None = None,
    preset: str = "default",
    output: str = "cube",
    disp_range: str | tuple[int, int] | None = None,
    method: str = "mccnn",
    model: _Path | None = None,
    registration: str = "multi-baseline",
    solver: str = "exact",
    matching_image: str | None = None,
    warp_kernel: str | None = None,
    coarse_to_fine: str = "auto",
    white_reflectance: float | None = None,
    saturation: float | None = None,
    tuning: str | None = None,
    progress: Callable[[str, int, int], object] | None = None,
    store: _Path | None = None,
    frame: int = 0,
    frames: list[int] | None = None,
    overwrite: bool = False,
    arrays: bool = True,
    skip_done: bool = False,
    create_only: bool = False,
    reuse: bool = True,
    previous: FrameCarry | None = None,
    frame_darks: dict[str, _Image] | None = None,
    background_write: bool = False,
    previous_write: PendingWrite | None = None,
) -> dict[str, Any]: ...
@final
class FrameCarry:
    """What one frame of a sequence hands to the next (opaque)."""

@final
class PendingWrite:
    """A frame being written into a store on a thread of its own."""

    def wait(self) -> float: ...

def read_capture(path: _Path) -> npt.NDArray[np.uint8] | npt.NDArray[np.uint16]: ...
def discover_frames(
    rig: Rig, folder: _Path, layout: str | None = None, frames: str = "all"
) -> list[tuple[int, list[str]]]: ...
def read_envi(path: _Path) -> tuple[npt.NDArray[np.float32], list[float] | None, list[str] | None]: ...
def write_envi(
    path: _Path,
    cube: npt.NDArray[Any],
    wavelengths: list[float] | None = None,
    band_names: list[str] | None = None,
    description: str = "anaglyph cube",
) -> None: ...
def read_pfm(path: _Path) -> npt.NDArray[np.float32]: ...
def write_pfm(path: _Path, array: npt.NDArray[np.float32]) -> None: ...
def read_image(path: _Path) -> npt.NDArray[np.float32]: ...
