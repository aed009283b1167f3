"""Kannala–Brandt fisheye as OpenCV's cv2.fisheye: θd = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸), m = θd·(x, y)/r."""
from __future__ import annotations

import functools
from typing import Any

import numpy as np

from appdgen.lens.numerics import (
    angle_rays,
    first_nonpositive,
    namespace,
    plane_of_rays,
    radial_project,
    radius_of_angle,
    scale_jacobian,
    scale_maps,
)

NAME = "kb4"
PARAMS: tuple[str, ...] = ("k1", "k2", "k3", "k4")
#: Below this r² the scale θd/r and its derivative take their limits at the axis (avoids 0/0).
_TINY = 1e-20


def _theta_d(theta: Any, coeffs: tuple[Any, ...]) -> Any:
    """Distorted angle θd(θ) (radians; any array namespace)."""
    k1, k2, k3, k4 = coeffs
    t2 = theta * theta
    return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def _slope(theta: np.ndarray, coeffs: tuple[float, ...]) -> np.ndarray:
    """dθd/dθ."""
    k1, k2, k3, k4 = coeffs
    t2 = theta * theta
    return 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))


def _scale(q: Any, coeffs: tuple[Any, ...]) -> Any:
    """m / (x, y) = θd(atan r)/r at q = r² (1 on the axis; any array namespace)."""
    xp = namespace(q)
    r = xp.sqrt(q)
    with np.errstate(all="ignore"):  # 0/0 on the axis, where the other branch is taken
        return xp.where(q > _TINY, _theta_d(xp.atan(r), coeffs) / r, 1.0)


def project(x: Any, y: Any, coeffs: tuple[Any, ...]) -> tuple[Any, Any]:
    """Undistorted normalized coordinates (unitless, z = 1) → distorted normalized coordinates (any array namespace;
    coefficients may be arrays that broadcast against x, y)."""
    return radial_project(x, y, lambda q: _scale(q, coeffs))


def jacobian(x: np.ndarray, y: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """(∂mx/∂x, ∂mx/∂y, ∂my/∂x, ∂my/∂y) of project (unitless)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    q = x * x + y * y
    r = np.sqrt(q)
    theta = np.arctan(r)
    with np.errstate(all="ignore"):
        s = np.where(q > _TINY, _theta_d(theta, coeffs) / r, 1.0)
        # ds/dq = (θd'(θ)/(1 + q) − s)/(2q); at the axis s = 1 + (k1 − 1/3)q + …
        ds_dq = np.where(q > _TINY, (_slope(theta, coeffs) / (1.0 + q) - s) / (2.0 * q), coeffs[0] - 1.0 / 3.0)
    return scale_jacobian(x, y, s, ds_dq)


@functools.lru_cache(maxsize=256)
def fold_angle(coeffs: tuple[float, ...]) -> float:
    """Smallest off-axis angle θ ≤ π (radians) where θd stops growing; inf when it grows up to π."""
    return first_nonpositive(lambda t: _slope(t, coeffs), np.pi)


def fold_radius(coeffs: tuple[float, ...]) -> float:
    """Undistorted normalized radius where θd stops growing; inf when it grows up to 90° (the plane's edge)."""
    return radius_of_angle(fold_angle(tuple(coeffs)))


def validate(coeffs: tuple[float, ...]) -> None:
    """Any finite coefficients are a Kannala–Brandt lens (its fold bounds the valid domain)."""


def unproject_rays(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...],
                   iterations: int = 30) -> tuple[np.ndarray, ...]:
    """Distorted normalized coordinates → unit rays (X, Y, Z), by Newton on θ; NaN past the fold (θ may exceed 90°)."""
    mx, my = np.asarray(mx, dtype=np.float64), np.asarray(my, dtype=np.float64)
    md = np.hypot(mx, my)
    theta = md.copy()
    with np.errstate(all="ignore"):
        for _ in range(iterations):
            step = (_theta_d(theta, coeffs) - md) / _slope(theta, coeffs)
            theta = theta - step
            if np.all(np.abs(step) < 1e-14):
                break
        ok = (np.abs(_theta_d(theta, coeffs) - md) < 1e-12) & (theta >= 0) & (theta < fold_angle(tuple(coeffs)))
    return angle_rays(np.where(ok, theta, np.nan), mx, my, md)


def plane_guess(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Newton's start for the inverse in the plane: the ray's (X/Z, Y/Z); NaN past 90° or the fold."""
    return plane_of_rays(*unproject_rays(mx, my, coeffs))


def maps(K: np.ndarray, coeffs: tuple[float, ...], new_K: np.ndarray,
         size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """float32 (map_x, map_y) for each output pixel of a pinhole camera new_K at size (w, h), in numpy."""
    # cv2.fisheye.initUndistortRectifyMap gives the same maps (tested) in 5.5x the time (4.0 vs 0.73 ms at 512x512,
    # benchmarks/bench_geometry.py on idle cores, docs/performance.md).
    return scale_maps(K, lambda q: _scale(q, coeffs), new_K, size)
