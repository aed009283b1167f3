"""Enhanced unified camera model (Khomutenko, Garcia, Martinet 2016): α, β.
m = (x, y)/(α ρ + (1 − α) z), ρ = √(β r² + z²)."""
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

NAME = "eucm"
PARAMS: tuple[str, ...] = ("alpha", "beta")


def _denominator(q: Any, coeffs: tuple[Any, ...]) -> tuple[Any, Any]:
    """α ρ + 1 − α at q = x² + y² (z = 1), and its derivative in q (any array namespace)."""
    alpha, beta = coeffs
    rho = namespace(q).sqrt(beta * q + 1.0)
    return alpha * rho + (1.0 - alpha), 0.5 * alpha * beta / rho


_scale, project, jacobian = quotient_model(_denominator)


@functools.lru_cache(maxsize=256)
def fold_angle(coeffs: tuple[float, ...]) -> float:
    """Smallest off-axis angle θ ≤ π (radians) where the model stops being one-to-one (inf: never)."""
    alpha, beta = coeffs

    def slope(theta):
        # Along the unit ray (sin θ, 0, cos θ): ρ(θ) = sin θ / den(θ) must grow.
        sin, cos = np.sin(theta), np.cos(theta)
        d = np.sqrt(beta * sin * sin + cos * cos)
        den = alpha * d + (1.0 - alpha) * cos
        dden = alpha * (beta - 1.0) * sin * cos / d - (1.0 - alpha) * sin
        return angle_slope(sin, cos, den, dden)

    return first_nonpositive(slope, np.pi)


def fold_radius(coeffs: tuple[float, ...]) -> float:
    """Undistorted normalized radius where the model stops being one-to-one; inf when that is at or past 90°."""
    return radius_of_angle(fold_angle(tuple(coeffs)))


def validate(coeffs: tuple[float, ...]) -> None:
    """α in [0, 1] and β > 0, where EUCM is a camera model (else AppdgenError)."""
    alpha, beta = coeffs
    if not (0.0 <= alpha <= 1.0 and beta > 0.0):
        raise AppdgenError(f"calibration: eucm needs 0 <= alpha <= 1 and beta > 0, got alpha={alpha:g} beta={beta:g}")


def unproject_rays(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """Distorted normalized coordinates → unit rays (X, Y, Z), closed form; NaN outside the image of the domain."""
    alpha, beta = coeffs
    mx, my = np.asarray(mx, dtype=np.float64), np.asarray(my, dtype=np.float64)
    r2 = mx * mx + my * my
    with np.errstate(all="ignore"):
        mz = (1.0 - beta * alpha * alpha * r2) / (alpha * np.sqrt(1.0 - (2.0 * alpha - 1.0) * beta * r2) + 1.0 - alpha)
        rays = unit_rays(mx, my, mz)
    return within_angle(rays, fold_angle(tuple(coeffs)))


def plane_guess(mx: np.ndarray, my: np.ndarray, coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Newton's start for the inverse in the plane: the closed-form ray's (X/Z, Y/Z); NaN past 90°."""
    return plane_of_rays(*unproject_rays(mx, my, coeffs))


def maps(K: np.ndarray, coeffs: tuple[float, ...], new_K: np.ndarray,
         size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """float32 (map_x, map_y) for each output pixel of a pinhole camera new_K at size (w, h), in numpy."""
    return scale_maps(K, lambda q: _scale(q, coeffs), new_K, size)
