"""APPD: average pixel position difference between two rectifications, in raw pixels or % of the diagonal."""
from __future__ import annotations

import cv2
import numpy as np

from appdgen.calibration import Calibration
from appdgen.maps import Rectification, rectify


def appd_px(a: Rectification, b: Rectification) -> float:
    """Mean over the output grid of ‖M̂a(p) − M̂b(p)‖₂, in raw pixels."""
    if a.size != b.size:
        raise ValueError(f"rectifications differ in output size: {a.size} vs {b.size}")
    # cv2's element-wise ops are fast (numpy's hypot is ~3x slower); numpy's float64 pairwise sum is the same
    # in every process, where cv2.mean's last bits were seen to differ between the main process and workers.
    distance = cv2.magnitude(cv2.subtract(a.map_x, b.map_x), cv2.subtract(a.map_y, b.map_y))
    return float(distance.mean(dtype=np.float64))


def px_to_pct(appd: float, calib: Calibration) -> float:
    """APPD in raw pixels → % of the raw image diagonal √(W²+H²)."""
    return appd * 100.0 / calib.diagonal


def appd(reference: Calibration, perturbed: Calibration, size: tuple[int, int] | None = None) -> tuple[float, float]:
    """(APPD in raw pixels, APPD in % of the raw diagonal) between two calibrations at an output size."""
    if reference.size != perturbed.size:
        raise ValueError(f"calibrations differ in raw size: {reference.size} vs {perturbed.size}")
    value = appd_px(rectify(reference, size), rectify(perturbed, size))
    return value, px_to_pct(value, reference)
