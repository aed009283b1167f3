"""Procedural raw frames: random street scenes seen through a camera with calibration Θ (lens distortion included).

Each scene is drawn as an ideal pinhole image on a canvas large enough to hold every raw pixel's
undistorted position, then resampled: raw pixel (u, v) takes the canvas colour at K·undistort(u, v).
So straight 3-D edges come out bowed as through the real lens, and rectifying with Θ straightens them.
A lens one canvas cannot hold (rays MAX_CANVAS_ANGLE or more off-axis, fisheyes past 90° included, or a canvas
over MAX_CANVAS_AREA) is drawn on the faces of a cube around the camera instead (cubemap): raw pixel (u, v)
takes the colour its ray (pixel_rays) hits; pixels without a ray, outside a fisheye's image circle, are black.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.calib.formats import native_suffix
from appdgen.dataset.images import write_image
from appdgen.errors import AppdgenError
from appdgen.geometry.distortion import pixel_rays, radial_fold_radius, undistort_pixels
from appdgen.synth.cubemap import CubeMaps, cube_maps, render_cube
from appdgen.synth.raster import Canvas
from appdgen.synth.street import CAR, MOUNTS, Mount, Scene, random_street
from appdgen.util.distribute import run_unordered

__all__ = ["CAR", "MOUNTS", "Mount", "calibration_name", "frame_name", "frame_rng", "render_frame", "render_ideal",
           "scale_calibration",
           "synthesize"]

MARGIN = 3  # canvas pixels beyond the outermost sample: room for bilinear taps and anti-aliased edges
MAX_CANVAS_AREA = 16  # × the raw image area; more is drawn on a cube of canvases instead
MAX_CANVAS_ANGLE = 80.0  # degrees off-axis: rays further out are drawn on a cube (one canvas stretches them too far)


def scale_calibration(calib: Calibration, scale: float) -> Calibration:
    """Θ of the same lens on a sensor `scale` times as large: size and K scaled (pixels), distortion unchanged.

    Pixel centres sit at integer coordinates, so a pixel's edge at −0.5 stays at −0.5: c' = (c + 0.5)·s − 0.5.
    """
    if not (math.isfinite(scale) and scale > 0):
        raise AppdgenError(f"scale must be a positive number, got {scale!r}")
    if scale == 1.0:
        return calib
    return calib.replace(
        width=round(calib.width * scale), height=round(calib.height * scale),
        fx=calib.fx * scale, fy=calib.fy * scale,
        cx=(calib.cx + 0.5) * scale - 0.5, cy=(calib.cy + 0.5) * scale - 0.5,
    )


def frame_rng(seed: int, index: int) -> np.random.Generator:
    """The generator for frame `index` of a run seeded `seed`: independent of the order frames are made in."""
    return np.random.default_rng(np.random.SeedSequence([seed, index]))


def _pixel_grid(calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Raw pixel centres (u, v) of calib's frame, float64 (H, W) each."""
    return np.meshgrid(np.arange(calib.width, dtype=np.float64), np.arange(calib.height, dtype=np.float64))


def _canvas_maps(calib: Calibration, x: np.ndarray, y: np.ndarray) -> tuple | None:
    """cv2.remap maps raw pixel → canvas pixel (float32), the canvas's K and size (w, h), pixels, from each raw
    pixel's undistorted position (x, y); None when the canvas would exceed MAX_CANVAS_AREA raw frames."""
    ideal_u, ideal_v = calib.fx * x + calib.cx, calib.fy * y + calib.cy
    # Integer offsets keep the canvas pixel grid aligned with the ideal image's, so both draw alike.
    ox, oy = math.ceil(MARGIN - ideal_u.min()), math.ceil(MARGIN - ideal_v.min())
    size = (math.ceil(ideal_u.max()) + ox + MARGIN + 1, math.ceil(ideal_v.max()) + oy + MARGIN + 1)
    if size[0] * size[1] > MAX_CANVAS_AREA * calib.width * calib.height:
        return None
    K = calib.K
    K[0, 2] += ox
    K[1, 2] += oy
    return (ideal_u + ox).astype(np.float32), (ideal_v + oy).astype(np.float32), K, size


@functools.lru_cache(maxsize=8)
def _lens_maps(calib: Calibration) -> tuple | CubeMaps:
    """How the raw frame is resampled: one pinhole canvas's maps (_canvas_maps) when it holds every pixel's
    ray under MAX_CANVAS_ANGLE within MAX_CANVAS_AREA, else a cube around the camera (cubemap)."""
    u, v = _pixel_grid(calib)
    x, y = undistort_pixels(u, v, calib, on_failure="nan")
    reach = math.tan(math.radians(MAX_CANVAS_ANGLE)) ** 2
    if np.all(np.isfinite(x) & np.isfinite(y)) and np.max(x * x + y * y) < reach:
        maps = _canvas_maps(calib, x, y)
        if maps is not None:
            return maps
    X, Y, Z = pixel_rays(u, v, calib)
    dark = ~np.isfinite(Z)
    # A lens one-to-one up to 90° ends where it sees no more: black outside its image circle, as a real fisheye.
    # One that folds before (radtan with strong barrel) is a model used past its domain: refuse it.
    if np.any(dark) and math.isfinite(radial_fold_radius(calib)):
        i = int(np.flatnonzero(dark.ravel())[0])
        raise AppdgenError(
            f"distortion cannot be inverted at {int(dark.sum())} raw pixel(s), e.g. ({u.ravel()[i]:.0f}, "
            f"{v.ravel()[i]:.0f}): the {calib.model} model folds over inside the frame"
        )
    return cube_maps(X, Y, Z)


def _ideal(calib: Calibration, scene: Scene) -> np.ndarray:
    """The scene as a perfect pinhole camera with K of calib would see it (BGR uint8, raw size)."""
    canvas = Canvas(calib.K, calib.size, scene.camera)
    scene.draw(canvas)
    return canvas.image


def _distorted(maps: tuple | CubeMaps, scene: Scene) -> np.ndarray:
    """The scene through a lens's maps (_lens_maps: BGR uint8, raw size), before sensor effects."""
    if isinstance(maps, CubeMaps):
        return render_cube(maps, scene.camera, scene.draw)
    map_x, map_y, K, size = maps
    canvas = Canvas(K, size, scene.camera)
    scene.draw(canvas)
    return cv2.remap(canvas.image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _sensor(image: np.ndarray, scene: Scene) -> np.ndarray:
    """Lens softness and sensor noise, as the scene chose them."""
    out = image.astype(np.float32)
    if scene.blur > 0.05:
        out = cv2.GaussianBlur(out, (0, 0), scene.blur)
    out += np.random.default_rng(scene.noise_seed).normal(0.0, scene.noise, out.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def render_frame(calib: Calibration, rng: np.random.Generator, scale: float = 1.0, mount: Mount = CAR) -> np.ndarray:
    """A random street as a raw frame of the camera Θ (scaled by `scale`): (H, W, 3) uint8, BGR as cv2 uses."""
    calib = scale_calibration(calib, scale)
    scene = random_street(rng, mount)
    maps = _lens_maps(calib)
    frame = _sensor(_distorted(maps, scene), scene)
    if isinstance(maps, CubeMaps):
        frame[maps.dark] = 0  # no light outside the image circle: not even blur or sensor noise
    return frame


def render_ideal(calib: Calibration, rng: np.random.Generator, scale: float = 1.0, mount: Mount = CAR) -> np.ndarray:
    """The scene render_frame would draw from rng in this state, as an ideal pinhole image (no lens, no noise)."""
    return _ideal(scale_calibration(calib, scale), random_street(rng, mount))


def calibration_name(calib: Calibration) -> str:
    """File name of a synth folder's calibration: calibration.yaml, or calibration.json for models OpenCV YAML
    cannot hold (ds, eucm)."""
    return "calibration" + native_suffix(calib)


def frame_name(index: int) -> str:
    """File name of frame `index` in a synth folder."""
    return f"frame_{index:06d}.png"


def write_frames(indices: range, calib: Calibration, out: Path, seed: int, scale: float, mount: Mount) -> int:
    """Render and write frames `indices` (one task's chunk) with OpenCV on one thread; returns how many."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # --jobs says how many cores: one process each
    try:
        for index in indices:
            write_image(out / frame_name(index), render_frame(calib, frame_rng(seed, index), scale, mount))
    finally:
        cv2.setNumThreads(threads)  # jobs == 1 runs in the caller's process: leave its setting as it was
    return len(indices)


def frame_chunks(frames: int, jobs: int) -> list[range]:
    """Index ranges small enough for a live progress line and an even finish, large enough to amortise a task."""
    size = 1 if jobs == 1 else max(1, min(8, frames // (4 * jobs)))
    return [range(i, min(i + size, frames)) for i in range(0, frames, size)]


def synthesize(
    calib: Calibration,
    frames: int,
    out_dir: str | Path,
    seed: int,
    scale: float = 1.0,
    progress: Callable[[int], object] | None = None,
    jobs: int = 1,
    mount: Mount = CAR,
) -> list[Path]:
    """Write frames frame_000000.png … of random streets seen by Θ (scaled), `jobs` processes at a time.

    Frame i depends on (seed, i) only, so the files are the same bytes for any `jobs`; progress(n) after each
    finished chunk of n frames.
    """
    if frames < 0:
        raise AppdgenError(f"frames must be >= 0, got {frames}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    work = functools.partial(write_frames, calib=calib, out=out, seed=seed, scale=scale, mount=mount)
    for done in run_unordered(work, frame_chunks(frames, jobs), jobs):
        if progress is not None:
            progress(done)
    return [out / frame_name(index) for index in range(frames)]
