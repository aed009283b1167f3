"""Decoding raw images: an image file read as 8-bit grey or BGR, converted to the samples' channels, 16-bit
pixels brought to 8 bits; errors name the file."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from appdgen.errors import AppdgenError


def read_image(path: Path, channels: int = 3) -> np.ndarray:
    """An 8-bit BGR image (H×W×3), or grey (H×W) for channels 1, from a file; AppdgenError naming the file when
    unreadable."""
    if not path.is_file():
        raise AppdgenError(f"{path}: no such image file")
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if channels == 1 else cv2.IMREAD_COLOR)
    if image is None:
        raise AppdgenError(f"{path}: not a readable image")
    return image


def as_channels(image: np.ndarray, channels: int) -> np.ndarray:
    """An 8-bit image with `channels` (1: grey H×W, 3: BGR H×W×3), converted when it has the other kind (a grey
    H×W×1 counts as grey)."""
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if channels == 3 else image
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if channels == 1 else image


def to_8bit(image: np.ndarray) -> np.ndarray:
    """An 8-bit image as it is; a 16-bit one (mono16, 16-bit PNG) by its high byte, value // 256: the dtype's full
    range maps to 0..255 whatever bit depth the sensor used, so every frame of a recording gets the same rule."""
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        return (image >> 8).astype(np.uint8)
    raise AppdgenError(f"{image.dtype} pixels: appdgen reads 8- or 16-bit images")
