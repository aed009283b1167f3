"""The device renderer: raw frames + per-image calibrations and crops → rectified images by grid_sample.

First version: maps come from the lens layer on the host and are moved to the frames' device (the device maps of
appdgen.geometry.maps replace them next; the signatures stay).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from appdgen import lens
from appdgen.calib.calibration import Calibration
from train.errors import TrainError

#: The interpolations grid_sample has, by appdgen's names (appdgen.geometry.remap.INTERPOLATIONS); no lanczos4.
DEVICE_INTERPOLATIONS: dict[str, str] = {"nearest": "nearest", "linear": "bilinear", "cubic": "bicubic"}


def maps_batch(calibs: Sequence[Calibration], new_ks: Sequence[np.ndarray], size: tuple[int, int],
               device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """(map_x, map_y): N×h×w raw-pixel positions of each output pixel of camera new_ks[i] at size (w, h)."""
    xs, ys = zip(*(lens.get(c.model).maps(c.K, c.coeffs, np.asarray(k, dtype=np.float64), size)
                   for c, k in zip(calibs, new_ks, strict=True)))
    return (torch.as_tensor(np.stack(xs), device=device, dtype=dtype),
            torch.as_tensor(np.stack(ys), device=device, dtype=dtype))


def remap_batch(raw: torch.Tensor, map_x: torch.Tensor, map_y: torch.Tensor, interp: str = "cubic") -> torch.Tensor:
    """N×C×h×w images sampled from raw N×C×H×W at the raw-pixel maps (N×h×w); uint8 in → uint8 out."""
    if interp not in DEVICE_INTERPOLATIONS:
        raise TrainError(f"--render device: interpolation {interp!r} is not available on the device; "
                         f"expected one of {', '.join(DEVICE_INTERPOLATIONS)}")
    height, width = raw.shape[-2:]
    # align_corners=True: −1 and +1 are the centres of the first and last raw pixels, as cv2.remap's integers.
    grid = torch.stack((map_x * (2.0 / (width - 1)) - 1.0, map_y * (2.0 / (height - 1)) - 1.0), dim=-1)
    image = raw if raw.is_floating_point() else raw.to(grid.dtype)
    # reflection with align_corners=True mirrors about the edge pixels' centres: build's BORDER_REFLECT_101.
    out = F.grid_sample(image.to(grid.dtype), grid, mode=DEVICE_INTERPOLATIONS[interp], padding_mode="reflection",
                        align_corners=True)
    if raw.dtype == torch.uint8:
        return out.round_().clamp_(0, 255).to(torch.uint8)
    return out.to(raw.dtype)


def rectify_batch(raw: torch.Tensor, calibs: Sequence[Calibration], new_ks: Sequence[np.ndarray],
                  size: tuple[int, int], interp: str = "cubic") -> torch.Tensor:
    """Rectified N×C×h×w images (size = (w, h)) of raw N×C×H×W frames, image i through calibs[i] and new_ks[i]."""
    if raw.ndim != 4 or raw.shape[0] != len(calibs):
        raise TrainError(f"rectify_batch: expected N×C×H×W frames for {len(calibs)} calibrations, got {tuple(raw.shape)}")
    map_x, map_y = maps_batch(calibs, new_ks, size, device=raw.device)
    return remap_batch(raw, map_x, map_y, interp)
