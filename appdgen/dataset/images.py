"""The build's image codec: samples encoded to (encode_image) and decoded from (decode_image) the stored
.png/.jpg/.npy bytes, and image files written atomically; errors name the file."""
from __future__ import annotations

import io
from pathlib import Path

import cv2
import numpy as np

from appdgen.dataset.encoders import DEFAULT_ENCODER, ENCODERS
from appdgen.dataset.layout import FORMATS
from appdgen.errors import AppdgenError
from appdgen.util.atomic import write_file


def encode_image(image: np.ndarray, ext: str, encoder: str = DEFAULT_ENCODER) -> bytes:
    """Encoded bytes for '.png' (through the PNG `encoder`, encoders.ENCODERS), '.jpg' (quality 95) or '.npy'."""
    if ext == FORMATS["npy"]:
        buffer = io.BytesIO()
        np.save(buffer, image, allow_pickle=False)
        return buffer.getvalue()
    if ext == FORMATS["png"]:
        return ENCODERS[encoder].encode(image)
    if ext != FORMATS["jpg"]:
        raise AppdgenError(f"unsupported image format {ext!r}; expected .png, .jpg or .npy")
    ok, data = cv2.imencode(ext, image, [cv2.IMWRITE_JPEG_QUALITY, 95])
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
