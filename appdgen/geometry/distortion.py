"""Projection and its inverse for a Calibration, through its lens model (appdgen.lens): float64, vectorized."""
from __future__ import annotations

import numpy as np

from appdgen import lens
from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.lens.numerics import newton_plane, plane_failures


def distort_normalized(x: np.ndarray, y: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates (unitless, z = 1) → distorted normalized coordinates, through calib's
    model."""
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
    """Raw pixel coordinates → undistorted normalized coordinates (unitless), by Newton on the model's Jacobian."""
    # Newton starts from the model's own guess (the distorted point for radtan, the closed-form or 1-D inverse
    # for fisheye models). A point that does not converge below TOLERANCE, converges past the fold-over where
    # the model is not invertible, or whose ray is at or past 90° off-axis is an AppdgenError (on_failure="raise")
    # or comes back NaN (on_failure="nan", as crop.py wants).
    if on_failure not in ("raise", "nan"):
        raise AppdgenError(f"undistort_pixels: on_failure must be 'raise' or 'nan', got {on_failure!r}")
    model = lens.get(calib.model)
    xd = (np.asarray(u, dtype=np.float64) - calib.cx) / calib.fx
    yd = (np.asarray(v, dtype=np.float64) - calib.cy) / calib.fy
    x, y = model.plane_guess(xd, yd, calib.coeffs)
    outside = ~np.isfinite(x)
    x, y = newton_plane(model.project, model.jacobian, calib.coeffs, xd, yd, x, y, iterations)
    failed, folded = plane_failures(model.project, model.jacobian, model.fold_radius(calib.coeffs), calib.coeffs,
                                    xd, yd, x, y)
    if on_failure == "nan":
        x, y = np.where(failed, np.nan, x), np.where(failed, np.nan, y)
    elif np.any(failed):
        raise AppdgenError(_failure_message(failed, folded, outside, xd, yd, calib))
    return x, y


def _failure_message(failed: np.ndarray, folded: np.ndarray, outside: np.ndarray, xd: np.ndarray, yd: np.ndarray,
                     calib: Calibration) -> str:
    """One line naming how many points failed, the first one's raw pixel and why."""
    i = int(np.flatnonzero(failed.ravel())[0])
    u, v = xd.ravel()[i] * calib.fx + calib.cx, yd.ravel()[i] * calib.fy + calib.cy
    if np.asarray(outside).ravel()[i]:
        why = "its ray is at or past 90° off-axis, or outside the lens model's domain"
    elif folded.ravel()[i]:
        why = "the lens model folds over there"
    else:
        why = "Newton's method did not converge"
    return (
        f"distortion cannot be inverted at {int(failed.sum())} point(s), e.g. raw pixel ({u:.1f}, {v:.1f}): {why} "
        f"({calib.model}: {', '.join(f'{n}={v:g}' for n, v in zip(calib.param_names[4:], calib.coeffs, strict=True))})"
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


def pixel_rays(u: np.ndarray, v: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw pixel coordinates → unit rays (X, Y, Z) in the camera frame, past 90° where the model sees there; NaN
    where the model has no valid preimage."""
    xd = (np.asarray(u, dtype=np.float64) - calib.cx) / calib.fx
    yd = (np.asarray(v, dtype=np.float64) - calib.cy) / calib.fy
    return lens.get(calib.model).unproject_rays(xd, yd, calib.coeffs)
