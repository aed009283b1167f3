"""APPD: average pixel position difference between two rectifications, in raw pixels or % of the diagonal."""
from __future__ import annotations

import cv2

from appdgen.calibration import Calibration
from appdgen.maps import Rectification, rectify


def appd_px(a: Rectification, b: Rectification) -> float:
    """Mean over the output grid of ‖M̂a(p) − M̂b(p)‖₂, in raw pixels."""
    if a.size != b.size:
        raise ValueError(f"rectifications differ in output size: {a.size} vs {b.size}")
    # cv2 keeps this at ~1 ms for 1392×512 (numpy needs ~3.5 ms); the mean is accumulated in double.
    distance = cv2.magnitude(cv2.subtract(a.map_x, b.map_x), cv2.subtract(a.map_y, b.map_y))
    return float(cv2.mean(distance)[0])


def px_to_pct(appd: float, calib: Calibration) -> float:
    """APPD in raw pixels → % of the raw image diagonal √(W²+H²)."""
    return appd * 100.0 / calib.diagonal


def appd(reference: Calibration, perturbed: Calibration, size: tuple[int, int] | None = None) -> tuple[float, float]:
    """(APPD in raw pixels, APPD in % of the raw diagonal) between two calibrations at an output size."""
    if reference.size != perturbed.size:
        raise ValueError(f"calibrations differ in raw size: {reference.size} vs {perturbed.size}")
    value = appd_px(rectify(reference, size), rectify(perturbed, size))
    return value, px_to_pct(value, reference)
