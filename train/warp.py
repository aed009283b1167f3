"""The device renderer: raw frames + per-image calibrations and crops → rectified images by grid_sample.

The maps come from appdgen.geometry.maps.raw_positions_batch, computed on the frames' device by the lens layer's
own projections (no lens equation here). `build` renders with cv2.remap on the CPU (appdgen.geometry.remap); this
is its counterpart for accelerators, within a measured bound of cv2.remap for the same maps (tests/test_warp.py).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.maps import raw_positions_batch
from train.errors import TrainError

#: The interpolations grid_sample has, by appdgen's names (appdgen.geometry.remap.INTERPOLATIONS); no lanczos4.
DEVICE_INTERPOLATIONS: dict[str, str] = {"nearest": "nearest", "linear": "bilinear", "cubic": "bicubic"}


def maps_batch(calibs: Sequence[Calibration], new_ks: Sequence[np.ndarray] | np.ndarray, size: tuple[int, int],
               device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """(map_x, map_y): N×h×w raw-pixel positions of each output pixel of camera new_ks[i] (3×3) at size (w, h),
    through calibs[i], computed on `device` in `dtype`."""
    like = torch.empty(0, device=device, dtype=dtype)
    # On a CPU image by image: a batch's N×h×w temporaries leave the cache. Measured on one core, 16 KITTI
    # images, alternating in one run: 0.86 vs 1.40 ms an image at 348x128, 23.7 vs 51.3 ms at 1392x512. An
    # accelerator takes the batch in one pass.
    chunk = 1 if like.device.type == "cpu" else None
    try:
        return raw_positions_batch(calibs, new_ks, size, like, chunk=chunk)
    except AppdgenError as e:
        raise TrainError(str(e)) from None


def remap_batch(raw: torch.Tensor, map_x: torch.Tensor, map_y: torch.Tensor, interp: str = "cubic") -> torch.Tensor:
    """N×C×h×w images sampled from raw N×C×H×W frames at raw-pixel maps (N×h×w, floating), like cv2.remap: uint8
    in → rounded, saturated uint8 out; floating in → the same floating dtype out."""
    if interp not in DEVICE_INTERPOLATIONS:
        raise TrainError(f"--render device: interpolation {interp!r} is not available on the device; "
                         f"expected one of {', '.join(DEVICE_INTERPOLATIONS)}")
    height, width = raw.shape[-2:]
    # align_corners=True: −1 and +1 are the centres of the first and last raw pixels, as cv2.remap's integers.
    grid = torch.stack((map_x * (2.0 / (width - 1)) - 1.0, map_y * (2.0 / (height - 1)) - 1.0), dim=-1)
    # Reflection with align_corners=True mirrors each kernel tap about the edge pixels' centres: build's
    # BORDER_REFLECT_101 (every M̂ position lies inside the frame, so only the kernel's tail reaches past it).
    out = F.grid_sample(raw.to(grid.dtype), grid, mode=DEVICE_INTERPOLATIONS[interp], padding_mode="reflection",
                        align_corners=True)
    if raw.dtype == torch.uint8:
        return out.round_().clamp_(0, 255).to(torch.uint8)
    return out.to(raw.dtype)


def rectify_batch(raw: torch.Tensor, calibs: Sequence[Calibration], new_ks: Sequence[np.ndarray] | np.ndarray,
                  size: tuple[int, int], interp: str = "cubic", dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Rectified N×C×h×w images (size = (w, h)) of raw N×C×H×W frames on any device, image i through calibs[i]
    and its crop's camera new_ks[i] (Crop.camera_matrix(size)); maps computed on raw's device in `dtype`."""
    if raw.ndim != 4 or raw.shape[0] != len(calibs):
        raise TrainError(f"rectify_batch: expected N×C×H×W frames for {len(calibs)} calibrations, "
                         f"got shape {tuple(raw.shape)}")
    wrong = [c.size for c in calibs if c.size != (raw.shape[3], raw.shape[2])]
    if wrong:
        raise TrainError(f"rectify_batch: frames are {raw.shape[3]}x{raw.shape[2]} but a calibration is "
                         f"{wrong[0][0]}x{wrong[0][1]}")
    map_x, map_y = maps_batch(calibs, new_ks, size, device=raw.device, dtype=dtype)
    return remap_batch(raw, map_x, map_y, interp)
