"""Double sphere (Usenko, Demmel, Cremers 2018): ξ, α. m = (x, y)/(α d2 + (1 − α)(ξ d1 + z)) on the plane z = 1."""
from __future__ import annotations

import functools
from typing import Any

import numpy as np

from appdgen.errors import AppdgenError
from appdgen.lens.numerics import (
    angle_slope,
    first_nonpositive,
    namespace,
    plane_of_rays,
    quotient_model,
    radius_of_angle,
    scale_maps,
    unit_rays,
    within_angle,
)

NAME = "ds"
PARAMS: tuple[str, ...] = ("xi", "alpha")


def _denominator(q: Any, coeffs: tuple[Any, ...]) -> tuple[Any, Any]:
    """α d2 + (1 − α)(ξ d1 + 1) at q = x² + y² (z = 1), and its derivative in q (any array namespace)."""
    xi, alpha = coeffs
    xp = namespace(q)
    d1 = xp.sqrt(q + 1.0)
    zz = xi * d1 + 1.0
    d2 = xp.sqrt(q + zz * zz)
    dzz = 0.5 * xi / d1
    dd2 = (0.5 + zz * dzz) / d2
    return alpha * d2 + (1.0 - alpha) * zz, alpha * dd2 + (1.0 - alpha) * dzz


_scale, project, jacobian = quotient_model(_denominator)


@functools.lru_cache(maxsize=256)
def fold_angle(coeffs: tuple[float, ...]) -> float:
    """Smallest off-axis angle θ ≤ π (radians) where the model stops being one-to-one (inf: never)."""
    xi, alpha = coeffs

    def slope(theta):
        # Along the unit ray (sin θ, 0, cos θ): ρ(θ) = sin θ / den(θ) must grow.
        sin, cos = np.sin(theta), np.cos(theta)
        zz = xi + cos
        d2 = np.sqrt(sin * sin + zz * zz)
        den = alpha * d2 + (1.0 - alpha) * zz
        dden = -alpha * xi * sin / d2 - (1.0 - alpha) * sin
        return angle_slope(sin, cos, den, dden)

    # The paper's projection domain z > −w2·d1 (eq. 43–45) can end before ρ peaks, or (for strongly negative ξ)
    # after: the model is valid up to whichever comes first.
    w1 = alpha / (1.0 - alpha) if alpha <= 0.5 else (1.0 - alpha) / alpha
    w2 = (w1 + xi) / np.sqrt(2.0 * w1 * xi + xi * xi + 1.0)
    return min(first_nonpositive(slope, np.pi), float(np.arccos(np.clip(-w2, -1.0, 1.0))))


def fold_radius(coeffs: tuple[float, ...]) -> float:
    """Undistorted normalized radius where the model stops being one-to-one; inf when that is at or past 90°."""
    return radius_of_angle(fold_angle(tuple(coeffs)))


def validate(coeffs: tuple[float, ...]) -> None:
    """α in [0, 1] and ξ > −1, where the double sphere is a camera model (else AppdgenError)."""
    xi, alpha = coeffs
    if not (0.0 <= alpha <= 1.0 and xi > -1.0):
        raise AppdgenError(f"calibration: double sphere needs 0 <= alpha <= 1 and xi > -1, "
                           f"got xi={xi:g} alpha={alpha:g}")


def unproject_rays(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """Distorted normalized coordinates → unit rays (X, Y, Z), closed form (paper eq. 47–49); NaN outside the image
    of the domain."""
    xi, alpha = coeffs
    mx, my = np.asarray(mx, dtype=np.float64), np.asarray(my, dtype=np.float64)
    r2 = mx * mx + my * my
    with np.errstate(all="ignore"):
        mz = (1.0 - alpha * alpha * r2) / (alpha * np.sqrt(1.0 - (2.0 * alpha - 1.0) * r2) + 1.0 - alpha)
        factor = (mz * xi + np.sqrt(mz * mz + (1.0 - xi * xi) * r2)) / (mz * mz + r2)
        rays = unit_rays(factor * mx, factor * my, factor * mz - xi)
    return within_angle(rays, fold_angle(tuple(coeffs)))


def plane_guess(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Newton's start for the inverse in the plane: the closed-form ray's (X/Z, Y/Z); NaN past 90°."""
    return plane_of_rays(*unproject_rays(mx, my, coeffs))


def maps(K: np.ndarray, coeffs: tuple[float, ...], new_K: np.ndarray,
         size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """float32 (map_x, map_y) for each output pixel of a pinhole camera new_K at size (w, h), in numpy."""
    return scale_maps(K, lambda q: _scale(q, coeffs), new_K, size)
