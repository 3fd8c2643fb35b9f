"""The pipeline's calls with Python conveniences around the compiled core: result objects,
tqdm progress bars, ``logging`` for warnings, and ``xarray`` export."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Union

import numpy as np

from . import _core
from ._core import Rig

if TYPE_CHECKING:  # pragma: no cover
    import xarray

logger = logging.getLogger("anaglyph")

PathLike = Union[str, "os.PathLike[str]"]
Progress = Callable[[str, int, int], None]


def _rig(rig: Rig | str) -> Rig:
    """A Rig, a preset name or a rig file path as a Rig."""
    if isinstance(rig, Rig):
        return rig
    if isinstance(rig, (str, os.PathLike)):
        if os.path.isfile(rig):
            return Rig.load(rig)
        return Rig.preset(str(rig))
    raise TypeError(f"rig: expected an anaglyph.Rig, a preset name or a rig file, got {type(rig).__name__}")


def _disparity_range(disp_range: Any, what: str = "disp_range") -> tuple[int, int]:
    """``(min, max)`` from a pair or a count of disparities (``N`` is ``(0, N)``)."""
    if isinstance(disp_range, (int, np.integer)) and not isinstance(disp_range, bool):
        return 0, int(disp_range)
    try:
        low, high = disp_range
        return int(low), int(high)
    except (TypeError, ValueError):
        raise TypeError(
            f"{what}: expected a (min, max) pair of integers or a number of disparities, got {disp_range!r}"
        ) from None


def match(
    left: np.ndarray,
    right: np.ndarray,
    disp_range: tuple[int, int] | int,
    method: str = "mccnn",
    contrast: str = "auto",
    channel: str = "luminance",
    model: PathLike | None = None,
    return_info: bool = False,
) -> np.ndarray | tuple[np.ndarray, dict[str, Any]]:
    """Disparity of a rectified pair through the full stereo chain (``anaglyph match``).

    ``x_right = x_left - d`` with ``min <= d < max`` for ``disp_range=(min, max)`` (an
    integer ``N`` means ``(0, N)``). Returns a float32 ``(H, W)`` map with **NaN where the
    disparity is unknown** (the CLI's PFM files hold +inf there); with
    ``return_info=True`` also a dict with the contrast vote and each stage's seconds.
    ``method``: ``mccnn`` (learned, the default), ``mccnn-lean`` (the learned cost with
    32 maps a layer: about twice as fast, a little less accurate across channels),
    ``mccnn-accurate`` (needs ``model``), ``census``, ``zncc`` or ``mi``. ``contrast``: ``auto`` negates the right image when the
    pair inverts contrast, ``same``, ``inverted`` or ``either`` (per pixel).

    >>> d = anaglyph.match(left, right, disp_range=(0, 64))   # doctest: +SKIP
    """
    low, high = _disparity_range(disp_range)
    model_path = os.fspath(model) if model is not None else None
    disparity, info = _core.match_pair_arrays(
        left, right, low, high, method=method, contrast=contrast, channel=channel, model=model_path
    )
    return (disparity, info) if return_info else disparity


@dataclass
class Simulation:
    """A scene rendered through a rig, in memory (``anaglyph simulate`` without files).

    ``captures``, ``whites`` (and ``darks`` with a dark signal): uint16 arrays per camera,
    exactly the CLI's 16-bit PNG files. ``reflectance`` (float32 ``(H, W, bands)``),
    ``disparity`` and ``depth`` (float32 ``(H, W)``): the truth per camera, at
    ``wavelengths`` (nm).
    """

    rig: Rig
    captures: dict[str, np.ndarray]
    whites: dict[str, np.ndarray]
    darks: dict[str, np.ndarray]
    reflectance: dict[str, np.ndarray]
    disparity: dict[str, np.ndarray]
    depth: dict[str, np.ndarray]
    wavelengths: np.ndarray
    exposures: dict[str, float]
    saturated_values: dict[str, int]

    @property
    def truth(self) -> dict[str, dict[str, np.ndarray]]:
        """The ground truth: ``{"reflectance": ..., "disparity": ..., "depth": ...}``."""
        return {"reflectance": self.reflectance, "disparity": self.disparity, "depth": self.depth}


def simulate(
    scene: str = "tabletop",
    rig: Rig | str = "paper-2x4",
    size: tuple[int, int] = (640, 480),
    seed: int = 0,
    noise: bool = True,
    supersampling: int = 2,
    vignetting: float = 0.0,
    dark: tuple[float, float] | None = None,
    frame: int = 0,
) -> Simulation:
    """Renders ``scene`` (``tabletop``, ``clutter``, ``periodic``, ``checkerboard``,
    ``tabletop-moving``, ``random`` or a scene file) through ``rig`` (a Rig, a preset name
    or a rig file) at ``size=(width, height)``, with sensor noise, unknown exposures and
    white boards. ``frame``: the frame of a sequence (``simulate --frames``): objects moved
    by their motion ``frame`` times, new noise, the seed's exposures (frame 0's white
    boards serve every frame).

    >>> sim = anaglyph.simulate("tabletop", rig="paper-2x4", size=(160, 120))  # doctest: +SKIP
    >>> sim.captures["r0c0"].dtype                                             # doctest: +SKIP
    dtype('uint16')
    """
    rig = _rig(rig)
    width, height = size
    out = _core.simulate(
        scene, rig, int(width), int(height), seed=seed, noise=noise, supersampling=supersampling,
        vignetting=vignetting, dark=dark, frame=frame,
    )
    return Simulation(rig=rig, **out)


def calibrate(
    boards: Mapping[str, np.ndarray],
    rig: Rig | str,
    pattern: tuple[int, int],
    reference: str | None = None,
    model: str = "homography",
) -> dict[str, dict[str, Any]]:
    """Each camera's map onto the reference camera through the plane of a checkerboard
    with ``pattern=(cols, rows)`` inner corners that every camera sees in ``boards``.

    Returns per camera ``homography`` (3x3), ``residual_rms_px``, ``residual_max_px``,
    ``rotation_deg`` (the map's turn at the image centre: beyond 90° for a camera mounted
    otherwise than the reference), ``seen`` (``"upright"``,
    ``"turned 180°"``, ...) and ``corners``. Pass ``{name: fit["homography"] ...}`` as ``reconstruct(calibration=...)``.
    """
    cols, rows = pattern
    return _core.calibrate(dict(boards), _rig(rig), (int(cols), int(rows)), reference=reference, model=model)


@dataclass
class View:
    """One reconstructed view: ``cube`` float32 ``(H, W, bands)`` (reflectance, NaN where
    nothing was measured; None with ``output="registered"``), ``disparity`` float32
    ``(H, W)`` per column step of the array (NaN: unknown), ``registered`` float32
    ``(H, W, channels)`` with ``output="registered"`` or ``"both"`` (NaN: unseen),
    ``cameras_seeing`` uint8 ``(H, W)``: how many cameras (the view's own included)
    measured each pixel, and ``visibility``, the view's summary of it."""

    name: str
    disparity: np.ndarray
    cube: np.ndarray | None = None
    registered: np.ndarray | None = None
    cameras_seeing: np.ndarray | None = None
    visibility: dict[str, Any] = field(default_factory=dict)
    neighbour_agreement: float | None = None


@dataclass
class Reconstruction:
    """A multispectral light field: a :class:`View` per camera, the band ``wavelengths``
    (nm), the ``channel_labels`` of a registered stack, the run's ``manifest`` (what the
    CLI's ``manifest.json`` records) and its ``warnings``."""

    views: dict[str, View]
    wavelengths: np.ndarray
    channel_labels: list[str]
    manifest: dict[str, Any]
    warnings: list[str]

    def __getitem__(self, name: str) -> View:
        return self.views[name]

    def __iter__(self):
        return iter(self.views.values())

    def __len__(self) -> int:
        return len(self.views)

    def to_xarray(self) -> "xarray.Dataset":
        """The light field as an ``xarray.Dataset`` with dims ``("view", "y", "x",
        "wavelength")`` and a ``wavelength`` coordinate in nm (needs ``xarray``)."""
        try:
            import xarray as xr
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("to_xarray needs xarray: pip install xarray") from e
        names = list(self.views)
        data: dict[str, Any] = {
            "disparity": (("view", "y", "x"), np.stack([v.disparity for v in self])),
        }
        if all(v.cameras_seeing is not None for v in self):
            data["visibility"] = (
                ("view", "y", "x"),
                np.stack([v.cameras_seeing for v in self]),
                {"long_name": "number of cameras that measured the pixel"},
            )
        if all(v.cube is not None for v in self):
            data["reflectance"] = (
                ("view", "y", "x", "wavelength"),
                np.stack([v.cube for v in self]),
                {"units": "1", "long_name": "reflectance"},
            )
        if all(v.registered is not None for v in self):
            data["registered"] = (("view", "y", "x", "channel"), np.stack([v.registered for v in self]))
        coords: dict[str, Any] = {
            "view": names,
            "wavelength": ("wavelength", np.asarray(self.wavelengths), {"units": "nm"}),
        }
        if "registered" in data:
            coords["channel"] = list(self.channel_labels)
        return xr.Dataset(data, coords=coords, attrs={"generator": self.manifest.get("generator", "anaglyph")})


def _progress(progress: bool | Progress | None) -> tuple[Any, Progress | None]:
    """A tqdm bar and its callback (``progress=True``), the caller's callback, or none."""
    if callable(progress):
        return None, progress
    if not progress:
        return None, None
    from tqdm.auto import tqdm  # type: ignore[import-untyped]

    bar = tqdm(total=1, desc="anaglyph", unit="view", leave=False)

    def update(stage: str, done: int, total: int) -> None:
        if bar.desc != stage:
            bar.set_description(stage, refresh=False)
        bar.total = total
        bar.n = done
        bar.refresh()

    return bar, update



def _captures(captures: Any, what: str = "captures") -> dict[str, Any]:
    if not isinstance(captures, Mapping):
        raise TypeError(f"{what}: expected a dict of camera name -> image, got {type(captures).__name__}")
    return dict(captures)


def _core_options(
    whites: Mapping[str, np.ndarray] | None = None,
    darks: Mapping[str, np.ndarray] | None = None,
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
    reuse: bool = True,
) -> dict[str, Any]:
    """The keyword arguments of ``_core.reconstruct`` for :func:`reconstruct`'s options
    (with its defaults) and a sequence's ``reuse``."""
    search: Any = disp_range
    if not (isinstance(disp_range, str) and disp_range == "auto"):
        search = _disparity_range(disp_range)
    if calibration is not None and not isinstance(calibration, Mapping):
        calibration = os.fspath(calibration)
    return dict(
        whites=_captures(whites, "whites") if whites is not None else None,
        darks=_captures(darks, "darks") if darks is not None else None,
        calibration=dict(calibration) if isinstance(calibration, Mapping) else calibration,
        views=list(views) if views is not None else None,
        preset=preset,
        output=output,
        disp_range=search,
        method=method,
        model=os.fspath(model) if model is not None else None,
        registration=registration,
        solver=solver,
        matching_image=matching_image,
        warp_kernel=warp_kernel,
        coarse_to_fine=coarse_to_fine,
        white_reflectance=white_reflectance,
        saturation=saturation,
        tuning=json.dumps(dict(tuning)) if tuning is not None else None,
        reuse=bool(reuse),
    )


def reconstruct(
    rig: Rig | str,
    captures: Mapping[str, np.ndarray],
    whites: Mapping[str, np.ndarray] | None = None,
    darks: Mapping[str, np.ndarray] | None = None,
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
    progress: bool | Progress = True,
) -> Reconstruction:
    """The multispectral light field of an array's captures (``anaglyph reconstruct``, in
    memory; the same pipeline and the same numbers).

    ``captures``, ``whites``, ``darks``: one image per camera of ``rig``, by name.
    ``calibration``: per camera a 3x3 homography onto the reference camera or a
    calibration file, or the folder ``anaglyph calibrate`` wrote. ``views``: the cameras
    whose views to reconstruct (default all). ``preset``: ``default``, ``fast`` or
    ``paper``. ``output``: ``cube``, ``registered`` or ``both``; ``registered`` alone
    registers only: it needs no white board or exposure (a camera without either keeps
    its capture as recorded, ``manifest["calibration"]`` says which) and runs no spectral
    stage (``manifest["stages"]``). ``disp_range``: ``"auto"``
    or ``(min, max)`` per column step. The other options are the CLI's by the same names;
    ``tuning`` holds the solve's tuning options (``{"no_refine": True, "scene_prior_clusters":
    8}``: ``reconstruct --help``'s Tuning options with underscores). ``progress``: a tqdm bar (True), none (False) or a
    callable ``(stage, done, total)``; an exception it raises stops the run at the next
    stage boundary and is raised here, as is a KeyboardInterrupt. Warnings go to the
    ``anaglyph`` logger.

    >>> rec = anaglyph.reconstruct(sim.rig, sim.captures, whites=sim.whites)  # doctest: +SKIP
    >>> rec["r0c0"].cube.shape                                                # doctest: +SKIP
    (120, 160, 24)
    """
    rig = _rig(rig)
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
    )
    bar, callback = _progress(progress)
    try:
        out = _core.reconstruct(rig, _captures(captures), progress=callback, **options)
    finally:
        if bar is not None:
            bar.close()
    for warning in out["warnings"]:
        logger.warning(warning)
    return _reconstruction(out)


def _reconstruction(out: dict[str, Any]) -> Reconstruction:
    """The :class:`Reconstruction` of what ``_core.reconstruct`` returned."""
    return Reconstruction(
        views={name: View(name=name, **view) for name, view in out["views"].items()},
        wavelengths=out["wavelengths"],
        channel_labels=out["channel_labels"],
        manifest=out["manifest"],
        warnings=out["warnings"],
    )
