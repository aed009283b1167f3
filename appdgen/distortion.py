"""The radial-tangential (plumb-bob) lens model in numpy: normalized coordinates in, normalized or pixels out."""
from __future__ import annotations

import numpy as np

from appdgen.calibration import Calibration


def distort_normalized(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized (x, y) → distorted normalized (xd, yd), OpenCV's formula."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (calib.k1 + r2 * (calib.k2 + r2 * calib.k3))
    xd = x * radial + 2.0 * calib.p1 * x * y + calib.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + calib.p1 * (r2 + 2.0 * y * y) + 2.0 * calib.p2 * x * y
    return xd, yd


def distort_to_pixels(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized (x, y) → raw pixel position (u, v)."""
    xd, yd = distort_normalized(x, y, calib)
    return calib.fx * xd + calib.cx, calib.fy * yd + calib.cy


def distortion_jacobian(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, ...]:
    """Partial derivatives (∂xd/∂x, ∂xd/∂y, ∂yd/∂x, ∂yd/∂y) of the normalized distortion."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (calib.k1 + r2 * (calib.k2 + r2 * calib.k3))
    dradial_dr2 = calib.k1 + r2 * (2.0 * calib.k2 + 3.0 * r2 * calib.k3)
    dxx = radial + 2.0 * x * x * dradial_dr2 + 2.0 * calib.p1 * y + 6.0 * calib.p2 * x
    dxy = 2.0 * x * y * dradial_dr2 + 2.0 * calib.p1 * x + 2.0 * calib.p2 * y
    dyy = radial + 2.0 * y * y * dradial_dr2 + 6.0 * calib.p1 * y + 2.0 * calib.p2 * x
    return dxx, dxy, dxy, dyy


def radial_fold_radius(calib: Calibration, r_max: float = 10.0) -> float:
    """Smallest undistorted radius (normalized) where r·radial(r) stops growing; inf when not below r_max."""
    # d/dr [r (1 + k1 r² + k2 r⁴ + k3 r⁶)] = 1 + 3 k1 q + 5 k2 q² + 7 k3 q³ with q = r². Scan, then bisect in
    # plain floats: LAPACK's root finder (np.roots) differed in the last bit between processes with different
    # BLAS threading, and that bit reached the crop.
    def slope(q: float) -> float:
        return 1.0 + q * (3.0 * calib.k1 + q * (5.0 * calib.k2 + q * 7.0 * calib.k3))

    grid = np.linspace(0.0, r_max * r_max, 4097)
    negative = np.nonzero(1.0 + grid * (3.0 * calib.k1 + grid * (5.0 * calib.k2 + grid * 7.0 * calib.k3)) <= 0)[0]
    if negative.size == 0:
        return float("inf")
    lo, hi = float(grid[negative[0] - 1]), float(grid[negative[0]])
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        lo, hi = (mid, hi) if slope(mid) > 0 else (lo, mid)
    return float(np.sqrt(lo))


def undistort_pixels(u: np.ndarray, v: np.ndarray, calib: Calibration, iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Raw pixel (u, v) → undistorted normalized (x, y) by Newton's method; NaN where it does not converge."""
    xd = (np.asarray(u, dtype=float) - calib.cx) / calib.fx
    yd = (np.asarray(v, dtype=float) - calib.cy) / calib.fy
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        ex, ey = distort_normalized(x, y, calib)
        ex, ey = ex - xd, ey - yd
        a, b, c, d = distortion_jacobian(x, y, calib)
        det = a * d - b * c
        dx, dy = (d * ex - b * ey) / det, (a * ey - c * ex) / det
        x, y = x - dx, y - dy
        if not np.abs(dx).max(initial=0.0) + np.abs(dy).max(initial=0.0) > 1e-13:
            break
    ex, ey = distort_normalized(x, y, calib)
    bad = ~(np.hypot(ex - xd, ey - yd) < 1e-11)
    x[bad], y[bad] = np.nan, np.nan
    return x, y
