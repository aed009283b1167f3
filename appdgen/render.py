"""Sample images: remap a raw image through M̂."""
from __future__ import annotations

import cv2
import numpy as np

from appdgen.errors import AppdgenError
from appdgen.maps import Rectification

INTERPOLATIONS = {
    "nearest": cv2.INTER_NEAREST,
    "linear": cv2.INTER_LINEAR,
    "cubic": cv2.INTER_CUBIC,
    "lanczos4": cv2.INTER_LANCZOS4,
}


def remap_image(raw: np.ndarray, rect: Rectification, interp: str = "lanczos4") -> np.ndarray:
    """The rectified, cropped and rescaled image remap(raw, M̂) at the rectification's output size."""
    if raw.shape[1] != rect.calib.width or raw.shape[0] != rect.calib.height:
        raise AppdgenError(
            f"image is {raw.shape[1]}x{raw.shape[0]} but the calibration is {rect.calib.width}x{rect.calib.height}"
        )
    if interp not in INTERPOLATIONS:
        raise AppdgenError(f"unknown interpolation {interp!r}; expected one of {', '.join(INTERPOLATIONS)}")
    maps = (rect.map_x, rect.map_y)
    if interp == "lanczos4":
        # For LANCZOS4 remap rounds float maps to these fixed-point ones (1/32 px) itself, tile by tile: the
        # same bytes, but converting once up front is cheaper (linear and cubic have float paths that differ;
        # tests/test_build.py compares).
        maps = cv2.convertMaps(rect.map_x, rect.map_y, cv2.CV_16SC2)
    # Reflection only matters for the kernel's tail: every M̂ position lies inside the raw frame.
    return cv2.remap(raw, *maps, INTERPOLATIONS[interp], borderMode=cv2.BORDER_REFLECT_101)
