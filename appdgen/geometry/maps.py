"""Rectification maps M̂: for each output pixel, the raw-image position (pixels) to sample."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from appdgen import lens
from appdgen.calib.calibration import Calibration
from appdgen.geometry.crop import Crop, check_output_size, valid_region


@dataclass(frozen=True)
class Rectification:
    """A calibration's crop R, output camera matrix K̂ (pixels) and float32 maps M̂ at one output size."""

    calib: Calibration
    crop: Crop
    new_camera_matrix: np.ndarray
    map_x: np.ndarray
    map_y: np.ndarray

    @property
    def size(self) -> tuple[int, int]:
        """Output size (width, height) in pixels."""
        return (self.map_x.shape[1], self.map_x.shape[0])


def rectify(calib: Calibration, size: tuple[int, int] | None = None, crop: Crop | None = None,
            max_fov: float | None = None) -> Rectification:
    """Crop R, K̂ and maps M̂ at an output size (default: raw size), computed at that size, never resized.

    `max_fov` (degrees, None = unbounded) bounds R's horizontal field of view (crop.valid_region); a given `crop`
    is used as it is.
    """
    size = check_output_size(calib, size or calib.size)
    crop = crop or valid_region(calib, max_fov=max_fov)
    new_k = crop.camera_matrix(size)
    map_x, map_y = lens.get(calib.model).maps(calib.K, calib.coeffs, new_k, size)
    return Rectification(calib, crop, new_k, map_x, map_y)


def rectification_maps(calib: Calibration, size: tuple[int, int] | None = None,
                       max_fov: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(map_x, map_y): float32 raw-pixel positions of M̂ at the output size (default: raw size)."""
    rect = rectify(calib, size, max_fov=max_fov)
    return rect.map_x, rect.map_y
