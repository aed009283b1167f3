"""Rectification maps M̂: for each output pixel, the raw-image position (pixels) to sample."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import array_api_compat
import numpy as np

from appdgen import lens
from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.crop import Crop, check_output_size, valid_region
from appdgen.lens.numerics import output_plane


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


def raw_positions(calib: Calibration, new_k: np.ndarray, size: tuple[int, int], like: Any) -> tuple[Any, Any]:
    """(map_x, map_y): h×w raw-pixel positions of M̂ for output camera new_k at size (w, h), as arrays of `like`'s
    namespace, device and floating dtype (e.g. a torch tensor on the training device); see raw_positions_batch."""
    map_x, map_y = raw_positions_batch([calib], [new_k], size, like)
    return map_x[0, ...], map_y[0, ...]


def raw_positions_batch(calibs: Sequence[Calibration], new_ks: Sequence[np.ndarray] | np.ndarray,
                        size: tuple[int, int], like: Any, chunk: int | None = None) -> tuple[Any, Any]:
    """(map_x, map_y): N×h×w raw-pixel positions, row i for calibs[i] and output camera new_ks[i] (3×3, pixels) at
    size (w, h), computed in `like`'s namespace, on its device, in its floating dtype, by the lens layer's own
    `project` (one model per batch; the coefficients broadcast as N×1×1 arrays), `chunk` images per pass (None:
    all at once; small chunks keep a CPU's temporaries in cache).

    Equal to rectify()'s maps (OpenCV's for radtan and rational, numpy's float32 ones otherwise) to ≤ 1e-3 px in
    float32 (tests/test_device_maps.py). Where float32 loses precision, and how it is kept:

    * Pixels. The only loss measured is the rounding of the raw pixel position itself, ≤ 1–2 ulp(u): 2.4e-4 px at
      KITTI's 1392 wide, 4.9e-4 px at 2880 wide (float64: ≤ 1.2e-4, the reference maps' own float32 rounding).
      It grows with the frame: float32 maps hold 1e-3 px up to ~8,000 px wide (ulp(8192) = 9.8e-4). Pixels are
      therefore formed last, u = fx·m_x + cx, from coordinates relative to the principal point.
    * K̂⁻¹. The output plane x = (j − ĉx)/f̂x, y = (i − ĉy)/f̂y is computed in float64 on the host (w + h numbers
      per image) and rounded once. The float32 alternative, j·(1/f̂x) − ĉx/f̂x on the device, cancels to
      ~ulp(1) normalized; measured no worse for these cameras (the pixel rounding dominates), but it is free.
    * Polynomials. The models evaluate them by Horner's rule on normalized coordinates (|x| ≲ 2), so no large
      terms cancel; kb4's θd/r takes its axis limit below r² = 1e-20 in every namespace.
    """
    if len({c.model for c in calibs}) != 1:
        raise AppdgenError(f"raw_positions_batch: one lens model per batch, got {sorted({c.model for c in calibs})}")
    new_ks = np.asarray(new_ks, dtype=np.float64).reshape(-1, 3, 3)
    if len(new_ks) != len(calibs):
        raise AppdgenError(f"raw_positions_batch: {len(calibs)} calibrations but {len(new_ks)} camera matrices")
    xp, device, dtype = array_api_compat.array_namespace(like), array_api_compat.device(like), like.dtype
    if not xp.isdtype(dtype, "real floating"):
        raise AppdgenError(f"raw_positions_batch: maps need a floating dtype, got {dtype}")
    step = chunk or len(calibs)
    parts = [_positions(calibs[i:i + step], new_ks[i:i + step], size, xp, device, dtype)
             for i in range(0, len(calibs), step)]
    if len(parts) == 1:
        return parts[0]
    return xp.concat([p[0] for p in parts]), xp.concat([p[1] for p in parts])


def _positions(calibs: Sequence[Calibration], new_ks: np.ndarray, size: tuple[int, int], xp: Any, device: Any,
               dtype: Any) -> tuple[Any, Any]:
    """raw_positions_batch of one chunk, its arguments checked."""
    planes = [output_plane(k, size) for k in new_ks]
    x = xp.asarray(np.stack([p[0] for p in planes]), dtype=dtype, device=device)  # N×1×w
    y = xp.asarray(np.stack([p[1] for p in planes]), dtype=dtype, device=device)  # N×h×1
    params = np.array([[c.fx, c.fy, c.cx, c.cy, *c.coeffs] for c in calibs], dtype=np.float64)
    params = xp.asarray(params[:, :, None, None], dtype=dtype, device=device)  # N×P×1×1
    fx, fy, cx, cy, *coeffs = (params[:, i, ...] for i in range(params.shape[1]))
    mx, my = lens.get(calibs[0].model).project(x, y, tuple(coeffs))
    return fx * mx + cx, fy * my + cy
