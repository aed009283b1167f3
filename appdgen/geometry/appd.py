"""APPD: average pixel position difference between two rectifications, in raw pixels or % of the diagonal."""
from __future__ import annotations

import cv2
import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.geometry.maps import Rectification, rectify

#: Output rows per block of the APPD reduction: the float32 scratch rows stay in cache (~180 KB at 1392 wide).
BLOCK_ROWS = 32


def appd_px(a: Rectification, b: Rectification) -> float:
    """Mean over the output grid of ‖M̂a(p) − M̂b(p)‖₂, in raw pixels."""
    if a.size != b.size:
        raise ValueError(f"rectifications differ in output size: {a.size} vs {b.size}")
    # Plain IEEE float32 ops in place: cv2.magnitude's result was seen to depend on array alignment in its
    # last bit, which broke byte-identical builds; numpy's sqrt is correctly rounded. Row blocks keep the
    # scratch in cache (4× faster than whole-image temporaries, which were memory-bound). Each block is summed
    # in float64 by cv2.sumElems: 8× faster than numpy's casting sum, the same value here (float32 terms rarely
    # round in a float64 sum), and tested not to depend on alignment, so the result depends on the output size
    # only, never on workers.
    width = a.map_x.shape[1]
    dx, dy = np.empty((BLOCK_ROWS, width), np.float32), np.empty((BLOCK_ROWS, width), np.float32)
    total = 0.0
    for row in range(0, a.map_x.shape[0], BLOCK_ROWS):
        rows = slice(row, row + BLOCK_ROWS)
        x, y = dx[: a.map_x[rows].shape[0]], dy[: a.map_x[rows].shape[0]]
        np.subtract(a.map_x[rows], b.map_x[rows], out=x)
        np.subtract(a.map_y[rows], b.map_y[rows], out=y)
        np.multiply(x, x, out=x)
        np.multiply(y, y, out=y)
        np.add(x, y, out=x)
        np.sqrt(x, out=x)
        total += cv2.sumElems(x)[0]
    return total / a.map_x.size


def px_to_pct(appd: float, calib: Calibration) -> float:
    """APPD in raw pixels → % of the raw image diagonal √(W²+H²)."""
    return appd * 100.0 / calib.diagonal


def appd(reference: Calibration, perturbed: Calibration, size: tuple[int, int] | None = None,
         max_fov: float | None = None) -> tuple[float, float]:
    """(APPD in raw pixels, APPD in % of the raw diagonal) between two calibrations at an output size.

    The calibrations may use different lens models (APPD compares maps); `max_fov` (degrees) bounds both crops.
    """
    if reference.size != perturbed.size:
        raise ValueError(f"calibrations differ in raw size: {reference.size} vs {perturbed.size}")
    value = appd_px(rectify(reference, size, max_fov=max_fov), rectify(perturbed, size, max_fov=max_fov))
    return value, px_to_pct(value, reference)
