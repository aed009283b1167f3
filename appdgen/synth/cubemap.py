"""Wide lenses: the scene on the faces of a cube around the camera, each an ideal pinhole canvas, resampled per ray.

One pinhole canvas holds rays under 90° off-axis only, and grows without bound as they near it. A fisheye's
pixels (past 90° for TUM VI's 190° lens) are drawn instead from up to six 90° canvases posed along ±x, ±y, ±z of
the camera: each raw pixel's ray (pixel_rays) picks the face it hits, and one cv2.remap over the faces laid side
by side (an atlas) resamples them all. Faces no pixel uses are not drawn.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from appdgen.synth.raster import Camera, Canvas

#: Rotations camera frame → face frame (rows: the face's x, y, z axes in camera terms): front, right, left,
#: down, up, back (camera axes x right, y down, z forward).
FACES = np.array([
    [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    [[0, 0, -1], [0, 1, 0], [1, 0, 0]],
    [[0, 0, 1], [0, 1, 0], [-1, 0, 0]],
    [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
    [[1, 0, 0], [0, 0, 1], [0, -1, 0]],
    [[-1, 0, 0], [0, 1, 0], [0, 0, -1]],
], dtype=np.float64)
MARGIN = 3  # face pixels beyond the 90° square: room for bilinear taps and anti-aliased edges at the seams
#: Quantile of the raw pixels' angular density the faces match: the T265's extrapolated corners are 2.7x as dense
#: as its centre (99th percentile 692 px/rad, median 295), which would make faces 6x the area for a few pixels.
FINE_QUANTILE = 0.9
MAX_FACE = 4096  # pixels: a face side no lens at sane sizes needs (cv2.remap's maps stay far below 32767)


@dataclass(frozen=True)
class CubeMaps:
    """Which faces to draw, their camera matrix and side (pixels), and cv2.remap maps raw pixel → atlas pixel."""

    faces: tuple[int, ...]
    K: np.ndarray
    side: int
    map_x: np.ndarray
    map_y: np.ndarray
    dark: np.ndarray  # raw pixels without a ray (outside the image circle): black


def face_focal(X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> float:
    """Face focal length (pixels per radian at its centre): the raw image's angular sampling density at its
    FINE_QUANTILE, so faces are as sharp as nearly all the frame (not as its most compressed extrapolated corner)."""
    rays = np.stack([X, Y, Z], -1)
    steps = np.concatenate([np.linalg.norm(np.diff(rays, axis=a), axis=-1).ravel() for a in (0, 1)])
    steps = steps[np.isfinite(steps) & (steps > 0)]  # chord ≈ angle between neighbours (radians)
    if steps.size == 0:
        return MAX_FACE / 2
    return float(min(1.0 / np.quantile(steps, 1.0 - FINE_QUANTILE), MAX_FACE / 2))


def cube_maps(X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> CubeMaps:
    """Maps from unit rays (X, Y, Z) per raw pixel (NaN: no ray) to an atlas of the faces they hit."""
    dark = ~(np.isfinite(X) & np.isfinite(Y) & np.isfinite(Z))
    rays = np.stack([np.where(dark, 0.0, X), np.where(dark, 0.0, Y), np.where(dark, 1.0, Z)], -1)
    local = np.einsum("fij,hwj->fhwi", FACES, rays)  # each ray in each face's frame
    hit = np.argmax(local[..., 2], axis=0)  # the face a ray points at most directly: its z is the largest
    faces = tuple(int(f) for f in np.unique(hit[~dark]))
    n = math.ceil(2.0 * face_focal(X, Y, Z))
    f, c = n / 2.0, (n - 1) / 2.0 + MARGIN
    side = n + 2 * MARGIN
    p = np.take_along_axis(local, hit[None, ..., None], axis=0)[0]
    tile = np.searchsorted(faces, hit)  # position of the hit face in the atlas, left to right
    map_x = f * p[..., 0] / p[..., 2] + c + tile * side
    map_y = f * p[..., 1] / p[..., 2] + c
    map_x[dark], map_y[dark] = -side, -side  # outside the atlas: the remap's constant border, black
    K = np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])
    return CubeMaps(faces, K, side, map_x.astype(np.float32), map_y.astype(np.float32), dark)


def render_cube(maps: CubeMaps, camera: Camera, draw) -> np.ndarray:
    """The raw image (BGR uint8) through the cube: draw(canvas) paints each used face posed from `camera`."""
    tiles = []
    for face in maps.faces:
        canvas = Canvas(maps.K, (maps.side, maps.side), Camera(R=FACES[face] @ camera.R, C=camera.C))
        draw(canvas)
        tiles.append(canvas.image)
    atlas = np.hstack(tiles) if tiles else np.zeros((1, 1, 3), np.uint8)
    return cv2.remap(atlas, maps.map_x, maps.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
