"""Reading and writing image files with errors that name the file."""
from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np

from appdgen.dataset.layout import FORMATS
from appdgen.util.atomic import write_file
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


def encode_image(image: np.ndarray, ext: str) -> bytes:
    """Encoded bytes for '.png' (compression level 1), '.jpg' (quality 95) or '.npy'."""
    if ext == FORMATS["npy"]:
        buffer = io.BytesIO()
        np.save(buffer, image, allow_pickle=False)
        return buffer.getvalue()
    params = {FORMATS["png"]: [cv2.IMWRITE_PNG_COMPRESSION, 1], FORMATS["jpg"]: [cv2.IMWRITE_JPEG_QUALITY, 95]}.get(ext)
    if params is None:
        raise AppdgenError(f"unsupported image format {ext!r}; expected .png, .jpg or .npy")
    ok, data = cv2.imencode(ext, image, params)
    if not ok:
        raise AppdgenError(f"could not encode image as {ext}")
    return data.tobytes()


def decode_image(data: bytes, ext: str, where: str) -> np.ndarray:
    """An image array as stored, from encoded '.png'/'.jpg' bytes (H×W×3 BGR, or H×W for a grey sample) or '.npy'
    bytes; AppdgenError naming `where`."""
    if ext == FORMATS["npy"]:
        try:
            return np.load(io.BytesIO(data), allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise AppdgenError(f"{where}: not a readable .npy array ({exc})") from None
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if image is None:
        raise AppdgenError(f"{where}: not a readable image")
    return image


def write_image(path: Path, image: np.ndarray) -> None:
    """Write an image atomically (temp file, then rename); format from the extension."""
    ext = path.suffix.lower().replace(".jpeg", ".jpg")
    write_file(path, encode_image(image, ext if ext in FORMATS.values() else FORMATS["png"]))
