"""Numerical pieces the lens models share: sign-change scans, Newton in the plane, radial-scale Jacobians, numpy maps.

Not a model (it is not in the registry): model modules import it so that each model file holds only its equations.
The forward projections (each model's ``project`` and what it calls) are written against the Python array API, so
the same equations run on numpy arrays and on torch tensors (appdgen.geometry.maps.raw_positions); ``namespace``
and ``plane_arrays`` pick the namespace. Scalar pieces (scans, Newton, the crop's solves) stay numpy.
"""
from __future__ import annotations

from typing import Any, Callable

import array_api_compat
import numpy as np

#: Newton in the plane stops once every point's distorted residual is below this (normalized units, ≈1e-7 px).
TOLERANCE = 1e-10
#: Nodes of the scans for where a model stops being one-to-one.
SCAN_NODES = 4097
HALF_PI = 0.5 * np.pi
#: Inputs that are numpy's (or become numpy arrays): the projections convert them to float64, as they always did.
_NUMPY_INPUTS = (np.ndarray, np.generic, float, int, list, tuple)


def _numpy_namespace() -> Any:
    """The namespace numpy inputs run in: numpy itself where it is an array-API namespace (2.0 on: the models'
    sqrt, where, atan … are the very functions array_api_compat.numpy re-exports), else array_api_compat's."""
    # array_api_compat.numpy starts with `from numpy import *`, which imports numpy.testing and numpy.f2py:
    # ~0.12 s of every build worker's and command's start, for functions numpy 2 already has under these names.
    if hasattr(np, "isdtype"):
        return np
    return array_api_compat.array_namespace(np.empty(0))


_NUMPY = _numpy_namespace()


def namespace(*arrays: Any) -> Any:
    """The array-API namespace of `arrays` (_numpy_namespace() for numpy arrays, scalars and lists)."""
    for a in arrays:  # a loop, not all(…): the crop's hot loop asks ~30 times per draw
        if not isinstance(a, _NUMPY_INPUTS):
            return array_api_compat.array_namespace(*arrays)
    return _NUMPY


def plane_arrays(x: Any, y: Any) -> tuple[Any, Any, Any]:
    """(xp, x, y): the namespace of plane points and the points in it; numpy inputs become float64 arrays, other
    arrays (torch tensors) keep their dtype and device."""
    xp = namespace(x, y)
    if xp is _NUMPY:
        return xp, np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    return xp, x, y


def first_nonpositive(slope: Callable[[float], float], hi: float, nodes: int = SCAN_NODES) -> float:
    """Smallest t in [0, hi] where slope(t) ≤ 0 (the last t with slope > 0 to bisection accuracy); inf if none."""
    # Scan, then bisect in plain floats: LAPACK's root finder (np.roots) differed in the last bit between processes
    # with different BLAS threading, and that bit reached the crop.
    grid = np.linspace(0.0, hi, nodes)
    negative = np.nonzero(~(slope(grid) > 0))[0]
    if negative.size == 0:
        return float("inf")
    if negative[0] == 0:
        return 0.0
    lo, hi = float(grid[negative[0] - 1]), float(grid[negative[0]])
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        lo, hi = (mid, hi) if slope(mid) > 0 else (lo, mid)
    return lo


def radius_of_angle(theta: float) -> float:
    """Undistorted normalized radius tan θ of an off-axis angle θ (radians); inf from 90° on (not in the plane)."""
    return float(np.tan(theta)) if theta < HALF_PI else float("inf")


def scale_jacobian(x: np.ndarray, y: np.ndarray, s: np.ndarray, ds_dq: np.ndarray) -> tuple[np.ndarray, ...]:
    """Jacobian of m = s(q)·(x, y), q = x² + y², from s and ds/dq: (∂mx/∂x, ∂mx/∂y, ∂my/∂x, ∂my/∂y)."""
    cross = 2.0 * x * y * ds_dq
    return s + 2.0 * x * x * ds_dq, cross, cross, s + 2.0 * y * y * ds_dq


def newton_plane(project: Callable, jacobian: Callable, coeffs: tuple[float, ...], xd: np.ndarray, yd: np.ndarray,
                 x: np.ndarray, y: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted (x, y) with project(x, y) = (xd, yd), by Newton on the 2×2 Jacobian from the start (x, y)."""
    with np.errstate(all="ignore"):  # points that diverge turn non-finite; callers check the residual
        for _ in range(iterations):
            ex, ey = project(x, y, coeffs)
            ex, ey = ex - xd, ey - yd
            if not np.any(np.maximum(np.abs(ex), np.abs(ey)) >= TOLERANCE):  # NaN (no preimage) cannot improve
                break
            dxx, dxy, dyx, dyy = jacobian(x, y, coeffs)
            det = dxx * dyy - dxy * dyx
            x, y = x - (dyy * ex - dxy * ey) / det, y - (dxx * ey - dyx * ex) / det
    return x, y


def plane_failures(project: Callable, jacobian: Callable, fold: float, coeffs: tuple[float, ...], xd: np.ndarray,
                   yd: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks of points (x, y) that do not solve project = (xd, yd), and of those past the model's valid domain."""
    with np.errstate(all="ignore"):
        ex, ey = project(x, y, coeffs)
        residual = np.maximum(np.abs(ex - xd), np.abs(ey - yd))
        dxx, dxy, dyx, dyy = jacobian(x, y, coeffs)
        # Newton can land on a root past the fold-over (beyond the valid radius), or where the tangential terms
        # make the Jacobian singular: the model is not invertible there.
        folded = ~(np.hypot(x, y) < fold) | ~(dxx * dyy - dxy * dyx > 0)
    return ~(residual < TOLERANCE) | folded, folded


def plane_rays(project: Callable, jacobian: Callable, fold: float, coeffs: tuple[float, ...], mx: np.ndarray,
               my: np.ndarray, iterations: int = 50) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit rays (X, Y, Z) of distorted normalized points of a pinhole-plane model, by Newton; NaN where it fails."""
    mx, my = np.asarray(mx, dtype=np.float64), np.asarray(my, dtype=np.float64)
    x, y = newton_plane(project, jacobian, coeffs, mx, my, mx.copy(), my.copy(), iterations)
    failed, _ = plane_failures(project, jacobian, fold, coeffs, mx, my, x, y)
    x, y = np.where(failed, np.nan, x), np.where(failed, np.nan, y)
    return unit_rays(x, y, np.ones_like(x))


def unit_rays(X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, Y, Z) scaled to unit length (NaN stays NaN)."""
    norm = np.sqrt(X * X + Y * Y + Z * Z)
    return X / norm, Y / norm, Z / norm


def angle_rays(theta: np.ndarray, mx: np.ndarray, my: np.ndarray, md: np.ndarray) -> tuple[np.ndarray, ...]:
    """Unit rays at off-axis angle θ (radians) in the direction of the distorted point (mx, my), |m| = md."""
    with np.errstate(all="ignore"):
        sin = np.where(md > 0, np.sin(theta) / md, 0.0)
    return mx * sin, my * sin, np.cos(theta)


def output_plane(new_K: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates of the output pixel centres of camera new_K: a row of x, a column of y."""
    w, h = size
    x = (np.arange(w, dtype=np.float64) - new_K[0, 2]) / new_K[0, 0]
    y = (np.arange(h, dtype=np.float64) - new_K[1, 2]) / new_K[1, 1]
    return x[None, :], y[:, None]


def scale_maps(K: np.ndarray, scale: Callable[[np.ndarray], np.ndarray], new_K: np.ndarray,
               size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """float32 maps of a radial-scale model m = scale(q)·(x, y), q = x² + y², for output camera new_K at size (w, h)."""
    # float32 throughout: the maps are float32 anyway, the error stays under 1e-4 px for frames up to a few
    # thousand pixels, and halving the memory traffic is what keeps maps within the speed budget (make bench).
    x, y = output_plane(new_K, size)
    x, y = x.astype(np.float32), y.astype(np.float32)
    s = scale(x * x + y * y)
    map_x = s * np.float32(K[0, 0]) * x
    map_x += np.float32(K[0, 2])
    s *= np.float32(K[1, 1]) * y
    s += np.float32(K[1, 2])
    return map_x, s


def plane_of_rays(X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates (X/Z, Y/Z) of rays; NaN for rays at or past 90° off-axis."""
    with np.errstate(all="ignore"):
        Z = np.where(Z > 0, Z, np.nan)
        return X / Z, Y / Z


def angle_of_rays(Z: np.ndarray) -> np.ndarray:
    """Off-axis angle θ (radians) of unit rays from their Z."""
    return np.arccos(np.clip(Z, -1.0, 1.0))


def radial_project(x: Any, y: Any, scale: Callable[[Any], Any]) -> tuple[Any, Any]:
    """m = scale(q)·(x, y), q = x² + y²: the projection of every radially symmetric model (any array namespace)."""
    _, x, y = plane_arrays(x, y)
    s = scale(x * x + y * y)
    return s * x, s * y


def quotient_jacobian(x: np.ndarray, y: np.ndarray,
                      denominator: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, ...]:
    """Jacobian of m = (x, y)/den(q), from den and its derivative in q (unified models: DS, EUCM)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    den, dden = denominator(x * x + y * y)
    return scale_jacobian(x, y, 1.0 / den, -dden / (den * den))


def quotient_model(denominator: Callable) -> tuple[Callable, Callable, Callable]:
    """(scale, project, jacobian) of a unified model m = (x, y)/den(q, coeffs), q = x² + y² (DS, EUCM), from its
    den(q, coeffs) → (den, dden/dq): each such model states only its denominator."""
    def scale(q: Any, coeffs: tuple[Any, ...]) -> Any:
        """m / (x, y) at q = r² (any namespace)."""
        return 1.0 / denominator(q, coeffs)[0]

    def project(x: Any, y: Any, coeffs: tuple[Any, ...]) -> tuple[Any, Any]:
        """Undistorted normalized coordinates (unitless, z = 1) → distorted normalized coordinates (any namespace)."""
        return radial_project(x, y, lambda q: scale(q, coeffs))

    def jacobian(x: np.ndarray, y: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
        """(∂mx/∂x, ∂mx/∂y, ∂my/∂x, ∂my/∂y) of project (unitless)."""
        return quotient_jacobian(x, y, lambda q: denominator(q, coeffs))

    return scale, project, jacobian


def angle_slope(sin: np.ndarray, cos: np.ndarray, den: np.ndarray, dden: np.ndarray) -> np.ndarray:
    """dρ/dθ·den² of ρ(θ) = sin θ/den(θ) given den and dden/dθ; −1 where den ≤ 0 (no valid projection)."""
    return np.where(den > 0, cos * den - sin * dden, -1.0)


def within_angle(rays: tuple[np.ndarray, np.ndarray, np.ndarray], limit: float) -> tuple[np.ndarray, ...]:
    """Unit rays with those at or past `limit` radians off-axis (or NaN) set to NaN."""
    with np.errstate(invalid="ignore"):
        ok = angle_of_rays(rays[2]) < limit
    return tuple(np.where(ok, c, np.nan) for c in rays)

