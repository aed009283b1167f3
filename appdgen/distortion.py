"""Projection and its inverse for a Calibration, through its lens model (appdgen.lens): float64, vectorized."""
from __future__ import annotations

import numpy as np

from appdgen import lens
from appdgen.calibration import Calibration
from appdgen.errors import AppdgenError

#: Newton stops once every point's distorted residual is below this (normalized units, ≈1e-7 px).
TOLERANCE = 1e-10


def distort_normalized(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates (unitless, z = 1) → distorted normalized coordinates, through calib's model."""
    return lens.get(calib.model).project(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), calib.coeffs)


def distort_to_pixels(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates (unitless) → raw (distorted) pixel coordinates (u, v)."""
    xd, yd = distort_normalized(x, y, calib)
    return calib.fx * xd + calib.cx, calib.fy * yd + calib.cy


def distortion_jacobian(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, ...]:
    """Partial derivatives (∂xd/∂x, ∂xd/∂y, ∂yd/∂x, ∂yd/∂y) of distort_normalized (unitless)."""
    return lens.get(calib.model).jacobian(x, y, calib.coeffs)


def radial_fold_radius(calib: Calibration) -> float:
    """Undistorted normalized radius below which calib's model is one-to-one; inf when it has none."""
    return lens.get(calib.model).fold_radius(calib.coeffs)


def undistort_pixels(
    u: np.ndarray, v: np.ndarray, calib: Calibration, iterations: int = 50, on_failure: str = "raise"
) -> tuple[np.ndarray, np.ndarray]:
    """Raw pixel coordinates → undistorted normalized coordinates (unitless), by Newton on the 2×2 Jacobian."""
    # A point that does not converge below TOLERANCE, or converges past the fold-over where the model is not
    # invertible, is an AppdgenError (on_failure="raise") or comes back NaN (on_failure="nan", as crop.py wants).
    if on_failure not in ("raise", "nan"):
        raise AppdgenError(f"undistort_pixels: on_failure must be 'raise' or 'nan', got {on_failure!r}")
    xd = (np.asarray(u, dtype=np.float64) - calib.cx) / calib.fx
    yd = (np.asarray(v, dtype=np.float64) - calib.cy) / calib.fy
    x, y = xd.copy(), yd.copy()  # start from the distorted point: exact when there is no distortion
    with np.errstate(all="ignore"):  # points that diverge turn non-finite and are caught below
        for _ in range(iterations):
            ex, ey = distort_normalized(x, y, calib)
            ex, ey = ex - xd, ey - yd
            if np.all(np.maximum(np.abs(ex), np.abs(ey)) < TOLERANCE):
                break
            dxx, dxy, dyx, dyy = distortion_jacobian(x, y, calib)
            det = dxx * dyy - dxy * dyx
            x, y = x - (dyy * ex - dxy * ey) / det, y - (dxx * ey - dyx * ex) / det
        failed, folded = _failures(x, y, xd, yd, calib)
    if on_failure == "nan":
        x, y = np.where(failed, np.nan, x), np.where(failed, np.nan, y)
    elif np.any(failed):
        raise AppdgenError(_failure_message(failed, folded, xd, yd, calib))
    return x, y


def _failures(x: np.ndarray, y: np.ndarray, xd: np.ndarray, yd: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Masks of points that did not converge (or folded over), and of those that folded over."""
    ex, ey = distort_normalized(x, y, calib)
    residual = np.maximum(np.abs(ex - xd), np.abs(ey - yd))
    dxx, dxy, dyx, dyy = distortion_jacobian(x, y, calib)
    # Newton can land on a root past the fold-over (r beyond where r·radial(r) stops growing), or where the
    # tangential terms make the Jacobian singular: the model is not invertible there.
    folded = ~(np.hypot(x, y) < radial_fold_radius(calib)) | ~(dxx * dyy - dxy * dyx > 0)
    return ~(residual < TOLERANCE) | folded, folded


def _failure_message(failed: np.ndarray, folded: np.ndarray, xd: np.ndarray, yd: np.ndarray, calib: Calibration) -> str:
    """One line naming how many points failed, the first one's raw pixel and why."""
    i = int(np.flatnonzero(failed.ravel())[0])
    u, v = xd.ravel()[i] * calib.fx + calib.cx, yd.ravel()[i] * calib.fy + calib.cy
    why = "the lens model folds over there" if folded.ravel()[i] else "Newton's method did not converge"
    return (
        f"distortion cannot be inverted at {int(failed.sum())} point(s), e.g. raw pixel ({u:.1f}, {v:.1f}): {why} "
        f"({calib.model}: {', '.join(f'{n}={v:g}' for n, v in zip(calib.param_names[4:], calib.coeffs))})"
    )


def project(points_xyz: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame 3-D points (…, 3), any length unit, z > 0 → raw (distorted) pixel coordinates (u, v)."""
    p = np.asarray(points_xyz, dtype=np.float64)
    if p.shape[-1] != 3:
        raise AppdgenError(f"project: points must have shape (..., 3), got {p.shape}")
    z = p[..., 2]
    if not np.all(z > 0):
        raise AppdgenError(f"project: {int(np.sum(~(z > 0)))} point(s) are not in front of the camera (z <= 0)")
    return distort_to_pixels(p[..., 0] / z, p[..., 1] / z, calib)
