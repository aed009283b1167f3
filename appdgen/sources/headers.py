"""Image file headers: size (pixels) and channels from a PNG/JPEG header, and whether the file is complete."""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import cv2

from appdgen.errors import AppdgenError

_PNG_START = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the empty IEND chunk every complete PNG ends with
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}  # IHDR colour type → channels (3: palette, read as colour)
_JPEG_START, _JPEG_END = b"\xff\xd8", b"\xff\xd9"
_JPEG_TAIL = 1024  # bytes searched for the end-of-image marker (some writers append a few bytes after it)


@dataclass(frozen=True)
class ImageHeader:
    """What a raw image's header says: size (pixels) and channels (1 grey, 3 colour, 2 or 4 with alpha)."""

    width: int
    height: int
    channels: int

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels from the image's header; AppdgenError naming the file."""
    return image_header(path).size


def image_header(path: Path) -> ImageHeader:
    """Size and channels from the PNG/JPEG header (else by decoding), after check_complete; errors name the file."""
    check_complete(path)
    try:
        with open(path, "rb") as handle:
            header = stream_header(handle)
            if header:
                return header
    except OSError as exc:
        raise AppdgenError(f"{path}: cannot read image ({exc.strerror or exc})") from None
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise AppdgenError(f"{path}: not a readable image")
    return ImageHeader(image.shape[1], image.shape[0], 1 if image.ndim == 2 else image.shape[2])


def stream_header(handle) -> ImageHeader | None:
    """Size and channels from the PNG/JPEG header of an open binary file (or BytesIO) at its start, else None."""
    head = handle.read(32)
    if head.startswith(_PNG_START) and head[12:16] == b"IHDR":
        width, height = struct.unpack(">II", head[16:24])
        return ImageHeader(width, height, _PNG_CHANNELS.get(head[25], 0))
    if head.startswith(_JPEG_START):
        return _jpeg_header(handle)
    return None


def truncation(data: bytes) -> str | None:
    """Why encoded PNG/JPEG bytes are cut short (no IEND chunk, no end-of-image marker near the end), or None."""
    if data.startswith(_PNG_START) and not data.endswith(_PNG_END):
        return "truncated PNG (no IEND chunk at its end)"
    if data.startswith(_JPEG_START) and _JPEG_END not in data[-_JPEG_TAIL:]:
        return f"truncated JPEG (no end-of-image marker in its last {_JPEG_TAIL} bytes)"
    return None


def check_complete(path: Path) -> None:
    """Refuse a PNG without its closing IEND chunk or a JPEG without its end-of-image marker: a cut-off copy has
    a good header and decodes without error, the missing rows grey."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(8)
            size = handle.seek(0, 2)
            handle.seek(max(size - _JPEG_TAIL, len(head)))
            problem = truncation(head + handle.read())
    except OSError as exc:
        raise AppdgenError(f"{path}: cannot read image ({exc.strerror or exc})") from None
    if problem:
        raise AppdgenError(f"{path}: {problem}")


def _jpeg_header(handle) -> ImageHeader | None:
    """Size and components from a JPEG's first start-of-frame marker, or None when the header is odd."""
    handle.seek(2)
    while True:
        marker = handle.read(2)
        if len(marker) < 2 or marker[0] != 0xFF:
            return None
        if 0xC0 <= marker[1] <= 0xCF and marker[1] not in (0xC4, 0xC8, 0xCC):
            data = handle.read(8)  # length, precision, height, width, components
            if len(data) < 8:
                return None
            return ImageHeader(struct.unpack(">H", data[5:7])[0], struct.unpack(">H", data[3:5])[0], data[7])
        length = handle.read(2)
        if len(length) < 2:
            return None
        handle.seek(struct.unpack(">H", length)[0] - 2, 1)




def header_problem(header: ImageHeader, size: tuple[int, int]) -> str | None:
    """Why an image with this header cannot be a raw image of a camera of `size`, or None."""
    if header.size != size:
        return f"is {header.width}x{header.height}, the calibration {size[0]}x{size[1]}"
    if header.channels not in (1, 3):
        return (f"has {header.channels} channels (alpha or CMYK); appdgen reads grey (1) or colour (3) images")
    return None
