"""The PNG encoders a build can write its samples with (`build --encoder`), one class each behind one interface,
and their registry ENCODERS, the one owner of the names.

Every encoder writes standard PNG that any reader opens (cv2.imdecode gives the pixels back bit for bit) and the
same bytes for the same pixels on every machine: its bytes depend on the library's version alone (recorded in
build.json), never on the CPU's feature path or on which other extras are installed. That is why there is no
`auto`: a build's bytes would then follow the machine. docs/performance.md has the measured table.
"""
from __future__ import annotations

import importlib.util
import struct
import zlib
from typing import Callable, ClassVar

import cv2
import numpy as np

from appdgen.errors import AppdgenError

#: PNG zlib level of the opencv encoder (the bytes every build before --encoder wrote).
OPENCV_PNG_LEVEL = 1
#: libdeflate level of the libdeflate encoder: level 1 was the fastest and the smallest of levels 1-3 over remapped
#: street frames (Sub filter: 30.9 / 49.6 ms and 1095.5 / 1097.9 kB a 1392x512 sample at levels 1 / 2; level 3 was
#: slower still and levels 2-4 larger than 1 at 348x128 too; docs/studies/build-performance-history.md).
LIBDEFLATE_LEVEL = 1
#: The eight bytes every PNG file starts with.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: PNG filter type of every row the libdeflate encoder writes (1 = Sub: each byte minus the byte one pixel left).
PNG_FILTER_SUB = 1


class Encoder:
    """A PNG encoder: `encode` an 8-bit image (grey H×W, or BGR H×W×3 as OpenCV holds it) to PNG bytes."""

    name: ClassVar[str]
    channels: ClassVar[tuple[int, ...]]  # the sample channel counts it writes
    package: ClassVar[str | None] = None  # the PyPI package it needs beyond OpenCV
    extra: ClassVar[str | None] = None  # the appdgen extra that installs it, when not a core dependency

    def available(self) -> bool:
        """Whether its library is installed here."""
        return self.package is None or importlib.util.find_spec(self.package) is not None

    @property
    def library(self) -> str:
        """The key of build.json's `libraries` that records version(): its package, or opencv (a core one)."""
        return self.package or "opencv"

    def version(self) -> str:
        """Its library's version, which (with the pixels) decides the bytes."""
        raise NotImplementedError

    def encode(self, image: np.ndarray) -> bytes:
        """PNG bytes of `image`."""
        raise NotImplementedError


class OpenCVEncoder(Encoder):
    """OpenCV's libpng at zlib level 1: every platform, grey and colour; the bytes builds wrote before --encoder."""

    name = "opencv"
    channels = (1, 3)

    def version(self) -> str:
        """OpenCV's version (it bundles libpng and zlib)."""
        return cv2.__version__

    def encode(self, image: np.ndarray) -> bytes:
        """PNG bytes through cv2.imencode."""
        ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, OPENCV_PNG_LEVEL])
        if not ok:
            raise AppdgenError("could not encode image as .png")
        return data.tobytes()


class FpngEncoder(Encoder):
    """fpng (PyPI `fpng`, a wrapper of R. Geldreich's fpng): several times faster than OpenCV's level 1, files a
    little larger (docs/performance.md); colour only (fpng writes 24/32-bit PNG). Its SSE4.1 path computes only
    the CRC-32 and Adler-32 checksums, so the bytes are the same without it (tests/test_encoders.py runs both)."""

    name = "fpng"
    channels = (3,)
    package = "fpng"
    extra = "fpng"

    def version(self) -> str:
        """The fpng package's version."""
        import fpng

        return fpng.__version__

    def encode(self, image: np.ndarray) -> bytes:
        """PNG bytes of the image in RGB order (PNG's), through fpng."""
        from fpng import fpng_ext

        if image.ndim != 3 or image.shape[2] != 3:
            raise AppdgenError("--encoder fpng writes colour images only (use --encoder opencv for --channels 1)")
        data = fpng_ext.encode_ndarray(np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)))
        if not data:  # the wrapper returns empty bytes on failure instead of raising
            raise AppdgenError("fpng could not encode the image")
        return data


def png_file(width: int, height: int, channels: int, idat: bytes | bytearray,
             crc32: Callable[[bytes, int], int] = zlib.crc32) -> bytes:
    """A PNG file's bytes: 8-bit grey (channels 1) or RGB (3), `idat` (the zlib stream of the filtered rows) as
    its one IDAT chunk; `crc32(data, start)` is any CRC-32 with zlib's signature (the checksum is one number)."""
    colour_type = {1: 0, 3: 2}[channels]
    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)  # deflate, adaptive filters, no interlace
    parts = [PNG_SIGNATURE]
    for tag, data in ((b"IHDR", header), (b"IDAT", idat), (b"IEND", b"")):
        parts += [struct.pack(">I", len(data)), tag, data, struct.pack(">I", crc32(data, crc32(tag, 0)))]
    return b"".join(parts)  # the one copy of the compressed stream


def sub_filtered_rows(image: np.ndarray) -> np.ndarray:
    """The PNG scanlines of an 8-bit grey H×W or BGR H×W×3 image in RGB order, each row filter byte 1 (Sub) then
    every byte minus the byte one pixel to its left (mod 256): H×(W·channels + 1) uint8."""
    channels = 1 if image.ndim == 2 else image.shape[2]
    # One copy at most: the BGR→RGB swap (cv2.cvtColor, 0.3 ms at 1392x512, five times numpy's strided [..., ::-1]).
    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if channels == 3 else np.ascontiguousarray(image)
    rows = rgb.reshape(image.shape[0], -1)
    out = np.empty((rows.shape[0], rows.shape[1] + 1), np.uint8)
    out[:, 0] = PNG_FILTER_SUB
    out[:, 1:channels + 1] = rows[:, :channels]  # the first pixel's left neighbour is 0
    # uint8 subtraction wraps modulo 256 exactly, whatever SIMD width numpy's loop uses: the same bytes everywhere.
    np.subtract(rows[:, channels:], rows[:, :-channels], out=out[:, channels + 1:])
    return out


class LibdeflateEncoder(Encoder):
    """PNG written here (Sub filter on every row) and compressed by libdeflate (PyPI `deflate`, which bundles it in
    its wheels) at level 1: grey and colour, 3-4x faster than OpenCV's level 1 (2.9x at 348x128, 3.8x at 1392x512)
    for files of the same size
    (docs/performance.md). libdeflate's output is fixed for a given libdeflate version: its CPU-specific code is in
    the checksums and the match finder's table set-up, which do not change the stream (its maintainer,
    ebiggers/libdeflate#400); tests/test_encoders.py pins the bytes.

    Why Sub (measured over remapped street frames, level 1): at 348x128 it was the fastest and smallest of
    Sub / Up / Average (2.40 / 2.52 / 2.56 ms, 82.3 / 84.7 / 83.0 kB); at 1392x512 as fast as Average, 2.8 % larger
    (30.9 ms both, 1095.5 / 1065.4 kB) and smaller than Up (31.6 ms, 1122.6 kB); None was 24 % larger and Paeth
    twice as slow (its predictor alone took 45 ms in numpy). Sub also needs no previous row: one numpy subtraction.
    """

    name = "libdeflate"
    channels = (1, 3)
    package = "deflate"

    def version(self) -> str:
        """The deflate package's version: its wheels bundle one libdeflate each (the package does not say which)."""
        import deflate

        return deflate.__version__

    def encode(self, image: np.ndarray) -> bytes:
        """PNG bytes of the image: Sub-filtered rows, libdeflate's zlib stream, libdeflate's CRC-32."""
        import deflate

        channels = 1 if image.ndim == 2 else image.shape[2]
        if image.dtype != np.uint8 or channels not in self.channels:
            raise AppdgenError(f"--encoder libdeflate writes 8-bit grey or colour images, not {image.dtype} "
                               f"with {channels} channels")
        idat = deflate.zlib_compress(sub_filtered_rows(image), LIBDEFLATE_LEVEL)
        return png_file(image.shape[1], image.shape[0], channels, idat, deflate.crc32)


#: --encoder choices → encoder, the one registry.
ENCODERS: dict[str, Encoder] = {e.name: e for e in (OpenCVEncoder(), FpngEncoder(), LibdeflateEncoder())}
#: The default: libdeflate, a core dependency (every install has it: a build's bytes must not depend on which
#: extras a machine has), 3-4x faster than OpenCV's level 1 with files of the same size, grey and colour, and a
#: well-kept library (libdeflate and its wrapper release regularly); fpng, faster still, stays an optional extra
#: with one release (docs/performance.md).
DEFAULT_ENCODER = "libdeflate"
#: What builds and plans from before --encoder wrote (their build.json/plan.json name none): OpenCV's PNG, whatever
#: DEFAULT_ENCODER becomes.
LEGACY_ENCODER = "opencv"


def get_encoder(name: str, channels: int = 3) -> Encoder:
    """The encoder `name`, installed here and able to write `channels`; AppdgenError naming --encoder otherwise."""
    encoder = ENCODERS.get(name)
    if encoder is None:
        raise AppdgenError(f"--encoder {name!r}: expected one of {', '.join(ENCODERS)}")
    if not encoder.available():
        install = f"appdgen[{encoder.extra}]" if encoder.extra else encoder.package
        raise AppdgenError(f"--encoder {name}: needs the {encoder.package} package (pip install '{install}')")
    if channels not in encoder.channels:
        raise AppdgenError(f"--encoder {name}: writes {'colour' if encoder.channels == (3,) else 'grey'} images "
                           f"only, not --channels {channels} (use --encoder {DEFAULT_ENCODER})")
    return encoder
