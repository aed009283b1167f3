"""Pinhole + OpenCV's rational model with thin prism: k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 (8-coefficient files:
s = 0)."""
from __future__ import annotations

import functools
from typing import Any

import cv2
import numpy as np

from appdgen.lens.numerics import first_nonpositive, plane_arrays, plane_rays
from appdgen.lens.radtan import plane_guess  # noqa: F401  (the same start: the distorted point)

NAME = "rational"
PARAMS: tuple[str, ...] = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")
#: Largest undistorted normalized radius searched for a fold (≈ 84° off-axis), as for radtan.
R_MAX = 10.0


def _radial(q: Any, coeffs: tuple[Any, ...]) -> tuple[Any, Any]:
    """Radial factor (1 + k1q + k2q² + k3q³)/(1 + k4q + k5q² + k6q³) at q = r², and its derivative in q (any
    array namespace)."""
    k1, k2, _, _, k3, k4, k5, k6 = coeffs[:8]
    num, den = 1.0 + q * (k1 + q * (k2 + q * k3)), 1.0 + q * (k4 + q * (k5 + q * k6))
    dnum, dden = k1 + q * (2.0 * k2 + 3.0 * k3 * q), k4 + q * (2.0 * k5 + 3.0 * k6 * q)
    return num / den, (dnum * den - num * dden) / (den * den)


def project(x: Any, y: Any, coeffs: tuple[Any, ...]) -> tuple[Any, Any]:
    """Undistorted normalized coordinates (unitless, z = 1) → distorted normalized coordinates (any array namespace;
    coefficients may be arrays that broadcast against x, y)."""
    p1, p2, s1, s2, s3, s4 = coeffs[2], coeffs[3], *coeffs[8:]
    _, x, y = plane_arrays(x, y)
    r2 = x * x + y * y
    radial, _ = _radial(r2, coeffs)
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x) + r2 * (s1 + s2 * r2)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy + r2 * (s3 + s4 * r2)
    return xd, yd


def jacobian(x: np.ndarray, y: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """(∂xd/∂x, ∂xd/∂y, ∂yd/∂x, ∂yd/∂y) of project (unitless)."""
    p1, p2, s1, s2, s3, s4 = coeffs[2], coeffs[3], *coeffs[8:]
    r2 = x * x + y * y
    radial, dradial = _radial(r2, coeffs)
    prism_x, prism_y = 2.0 * (s1 + 2.0 * s2 * r2), 2.0 * (s3 + 2.0 * s4 * r2)  # d(prism)/d(r²) · 2
    cross = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    dxx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x + prism_x * x
    dyy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x + prism_y * y
    return dxx, cross + prism_x * y, cross + prism_y * x, dyy


def project_axis(t: np.ndarray, fixed: np.ndarray, rows: np.ndarray,
                 coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(m_x, ∂m_x/∂x) at (x, y) = (t, fixed) where rows, else (m_y, ∂m_y/∂y) at (fixed, t); unitless."""
    p1, p2, s1, s2, s3, s4 = coeffs[2], coeffs[3], *coeffs[8:]
    # m_y(x, y) is m_x(y, x) with p1 ↔ p2 and s1, s2 → s3, s4: one formula serves rows and columns.
    a, b = np.where(rows, p1, p2), np.where(rows, p2, p1)
    c, d = np.where(rows, s1, s3), np.where(rows, s2, s4)
    tt = t * t
    r2 = tt + fixed * fixed
    radial, dradial = _radial(r2, coeffs)
    m = t * radial + 2.0 * a * (t * fixed) + b * (r2 + 2.0 * tt) + r2 * (c + d * r2)
    return m, radial + 2.0 * tt * dradial + 2.0 * a * fixed + 6.0 * b * t + 2.0 * (c + 2.0 * d * r2) * t


def fold_radius(coeffs: tuple[float, ...]) -> float:
    """Smallest undistorted radius where r·radial(r) stops growing or the denominator vanishes; inf past R_MAX."""
    return _fold_radius(tuple(coeffs[:8]), R_MAX)


@functools.lru_cache(maxsize=256)
def _fold_radius(radial_coeffs: tuple[float, ...], r_max: float) -> float:
    """fold_radius of the radial coefficients (cached: the crop and the inverse both ask, per sample)."""
    def slope(q):
        # d/dr [r·f(r²)] = f + 2 q f'(q); a non-positive denominator is a pole, where the model is meaningless.
        value, derivative = _radial(q, radial_coeffs)
        den = 1.0 + q * (radial_coeffs[5] + q * (radial_coeffs[6] + q * radial_coeffs[7]))
        return np.where(den > 0, value + 2.0 * q * derivative, -1.0)

    return float(np.sqrt(first_nonpositive(slope, r_max * r_max)))


def validate(coeffs: tuple[float, ...]) -> None:
    """Any finite coefficients are a rational lens (its poles bound the valid domain)."""


def unproject_rays(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """Distorted normalized coordinates → unit rays (X, Y, Z), by Newton in the plane; NaN where not invertible."""
    return plane_rays(project, jacobian, fold_radius(coeffs), coeffs, mx, my)


def maps(K: np.ndarray, coeffs: tuple[float, ...], new_K: np.ndarray,
         size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """float32 (map_x, map_y) for each output pixel of a pinhole camera new_K at size (w, h), by OpenCV (12 coeffs)."""
    return cv2.initUndistortRectifyMap(K, np.asarray(coeffs, dtype=np.float64), None, new_K, size, cv2.CV_32FC1)
