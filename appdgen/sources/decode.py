"""Decoding raw images: an image file or encoded bytes (a CompressedImage) read as 8-bit grey or BGR, converted to
the samples' channels, 16-bit pixels brought to 8 bits; errors name the file, or the frame.

Strict: JPEG goes through simplejpeg with strict=True, so a corrupt body is an error, not the grey rows OpenCV
returns with only a libjpeg warning on stderr (libjpeg-turbo's islow DCT and fancy upsampling, OpenCV's own
settings: the same pixels, tests/test_decoders.py, at about OpenCV's speed). Everything else (PNG, BMP, TIFF, …)
goes through OpenCV. A corruption whose bytes still form a valid entropy stream (no marker hit, no premature end)
decodes without a warning in any JPEG reader: JPEG has no checksum.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import simplejpeg

from appdgen.errors import AppdgenError

JPEG_START = b"\xff\xd8\xff"
#: channels → OpenCV's imread flag (None: as stored, 16-bit and alpha included).
_CV2_FLAGS = {1: cv2.IMREAD_GRAYSCALE, 3: cv2.IMREAD_COLOR, None: cv2.IMREAD_UNCHANGED}


def read_image(path: Path, channels: int = 3) -> np.ndarray:
    """An 8-bit BGR image (H×W×3), or grey (H×W) for channels 1, from a file; AppdgenError naming the file when
    unreadable or, for a JPEG, corrupt."""
    if not path.is_file():
        raise AppdgenError(f"{path}: no such image file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise AppdgenError(f"{path}: cannot read image ({exc.strerror or exc})") from None
    return decode_bytes(data, str(path), 1 if channels == 1 else 3)


def is_jpeg(data: bytes) -> bool:
    """Whether encoded bytes start as a JPEG (SOI then a marker)."""
    return data[:3] == JPEG_START


def decode_bytes(data: bytes, where: str, channels: int | None = None) -> np.ndarray:
    """An image from encoded bytes: grey H×W for channels 1, BGR H×W×3 for 3, as stored for None (grey or BGR for
    JPEG; OpenCV's IMREAD_UNCHANGED otherwise); AppdgenError naming `where` when it does not decode cleanly."""
    if is_jpeg(data):
        return _decode_jpeg(data, where, channels)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), _CV2_FLAGS[channels]) if data else None
    if image is None:
        raise AppdgenError(f"{where}: not a readable image")
    return image


def _decode_jpeg(data: bytes, where: str, channels: int | None) -> np.ndarray:
    """A JPEG decoded strictly (any libjpeg warning is an error: corrupt data, a premature end, bad markers)."""
    try:
        if channels is None:
            channels = 1 if simplejpeg.decode_jpeg_header(data)[2] == "Gray" else 3
        image = simplejpeg.decode_jpeg(data, colorspace="GRAY" if channels == 1 else "BGR", strict=True)
    except ValueError as exc:
        raise AppdgenError(f"{where}: corrupt JPEG ({str(exc).strip() or 'libjpeg refused it'})") from None
    return image[:, :, 0] if image.ndim == 3 and image.shape[2] == 1 else image


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
