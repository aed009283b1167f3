"""APPD: average pixel position difference between two rectifications, in raw pixels or % of the diagonal."""
from __future__ import annotations

import numpy as np

from appdgen.calibration import Calibration
from appdgen.maps import Rectification, rectify


def appd_px(a: Rectification, b: Rectification) -> float:
    """Mean over the output grid of ‖M̂a(p) − M̂b(p)‖₂, in raw pixels."""
    if a.size != b.size:
        raise ValueError(f"rectifications differ in output size: {a.size} vs {b.size}")
    # Plain IEEE float32 ops in place: cv2.magnitude's result was seen to depend on array alignment in its
    # last bit, which broke byte-identical builds; numpy's sqrt is correctly rounded and its sum pairwise.
    dx = np.subtract(a.map_x, b.map_x)
    dy = np.subtract(a.map_y, b.map_y)
    np.multiply(dx, dx, out=dx)
    np.multiply(dy, dy, out=dy)
    np.add(dx, dy, out=dx)
    np.sqrt(dx, out=dx)
    return float(dx.mean(dtype=np.float64))


def px_to_pct(appd: float, calib: Calibration) -> float:
    """APPD in raw pixels → % of the raw image diagonal √(W²+H²)."""
    return appd * 100.0 / calib.diagonal


def appd(reference: Calibration, perturbed: Calibration, size: tuple[int, int] | None = None) -> tuple[float, float]:
    """(APPD in raw pixels, APPD in % of the raw diagonal) between two calibrations at an output size."""
    if reference.size != perturbed.size:
        raise ValueError(f"calibrations differ in raw size: {reference.size} vs {perturbed.size}")
    value = appd_px(rectify(reference, size), rectify(perturbed, size))
    return value, px_to_pct(value, reference)
