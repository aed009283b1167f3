"""Pinhole + radial-tangential (OpenCV's 5-coefficient model, Brown–Conrady): k1, k2, p1, p2, k3."""
from __future__ import annotations

import functools
from typing import Any

import cv2
import numpy as np

from appdgen.lens.numerics import first_nonpositive, plane_arrays, plane_rays

NAME = "radtan"
PARAMS: tuple[str, ...] = ("k1", "k2", "p1", "p2", "k3")
#: Largest undistorted normalized radius searched for a fold (≈ 84° off-axis).
R_MAX = 10.0


def project(x: Any, y: Any, coeffs: tuple[Any, ...]) -> tuple[Any, Any]:
    """Undistorted normalized coordinates (unitless, z = 1) → distorted normalized coordinates (any array namespace;
    coefficients may be arrays that broadcast against x, y: one calibration per batch row)."""
    k1, k2, p1, p2, k3 = coeffs
    _, x, y = plane_arrays(x, y)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    return xd, yd


def jacobian(x: np.ndarray, y: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """(∂xd/∂x, ∂xd/∂y, ∂yd/∂x, ∂yd/∂y) of project (unitless)."""
    k1, k2, p1, p2, k3 = coeffs
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d(radial)/d(r²)
    dxx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    dxy = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    dyy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return dxx, dxy, dxy, dyy


def project_axis(t: np.ndarray, fixed: np.ndarray, rows: np.ndarray,
                 coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(m_x, ∂m_x/∂x) at (x, y) = (t, fixed) where rows, else (m_y, ∂m_y/∂y) at (fixed, t); unitless."""
    k1, k2, p1, p2, k3 = coeffs
    # m_y(x, y) is m_x(y, x) with p1 and p2 swapped, so one formula serves rows and columns at half the cost of
    # project + jacobian (the crop's boundary solve calls it ~16 times per crop; in-place ops spare allocations).
    a2, b = np.where(rows, 2.0 * p1, 2.0 * p2), np.where(rows, p2, p1)
    tt = t * t
    r2 = fixed * fixed
    r2 += tt
    radial = r2 * k3
    radial += k2
    radial *= r2
    radial += k1
    radial *= r2
    radial += 1.0
    slope = r2 * (3.0 * k3)  # d(radial)/d(r²) · 2t², then the rest of ∂m/∂t
    slope += 2.0 * k2
    slope *= r2
    slope += k1
    slope *= 2.0 * tt
    slope += radial
    slope += a2 * fixed
    slope += 6.0 * b * t
    m = t * radial
    m += a2 * (t * fixed)
    m += b * (r2 + 2.0 * tt)
    return m, slope


def fold_radius(coeffs: tuple[float, ...]) -> float:
    """Smallest undistorted radius (normalized) where r·radial(r) stops growing; inf when not below R_MAX."""
    k1, k2, _, _, k3 = coeffs
    return _fold_radius(k1, k2, k3, R_MAX)


@functools.lru_cache(maxsize=256)
def _fold_radius(k1: float, k2: float, k3: float, r_max: float) -> float:
    """fold_radius of the radial coefficients (cached: the crop and the inverse both ask, per sample)."""
    # d/dr [r (1 + k1 r² + k2 r⁴ + k3 r⁶)] = 1 + 3 k1 q + 5 k2 q² + 7 k3 q³ with q = r².
    def slope(q):
        return 1.0 + q * (3.0 * k1 + q * (5.0 * k2 + q * 7.0 * k3))

    return float(np.sqrt(first_nonpositive(slope, r_max * r_max)))


def validate(coeffs: tuple[float, ...]) -> None:
    """Any finite coefficients are a radial-tangential lens."""


def plane_guess(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Newton's start for the inverse: the distorted point itself (exact without distortion)."""
    return mx.copy(), my.copy()


def unproject_rays(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """Distorted normalized coordinates → unit rays (X, Y, Z), by Newton in the plane; NaN where not invertible."""
    return plane_rays(project, jacobian, fold_radius(coeffs), coeffs, mx, my)


def maps(K: np.ndarray, coeffs: tuple[float, ...], new_K: np.ndarray,
         size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """float32 (map_x, map_y) raw-pixel positions for each output pixel of a pinhole camera new_K at size (w, h)."""
    return cv2.initUndistortRectifyMap(K, np.asarray(coeffs, dtype=np.float64), None, new_K, size, cv2.CV_32FC1)
