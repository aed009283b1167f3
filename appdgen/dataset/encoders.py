"""The PNG encoders a build can write its samples with (`build --encoder`), one class each behind one interface,
and their registry ENCODERS, the one owner of the names.

Every encoder writes standard PNG that any reader opens (cv2.imdecode gives the pixels back bit for bit) and the
same bytes for the same pixels on every machine: its bytes depend on the library's version alone (recorded in
build.json), never on the CPU's feature path or on which other extras are installed. That is why there is no
`auto`: a build's bytes would then follow the machine. docs/performance.md has the measured table.
"""
from __future__ import annotations

import importlib.util
from typing import ClassVar

import cv2
import numpy as np

from appdgen.errors import AppdgenError

#: PNG zlib level of the opencv encoder (the bytes every build before --encoder wrote).
OPENCV_PNG_LEVEL = 1


class Encoder:
    """A PNG encoder: `encode` an 8-bit image (grey H×W, or BGR H×W×3 as OpenCV holds it) to PNG bytes."""

    name: ClassVar[str]
    channels: ClassVar[tuple[int, ...]]  # the sample channel counts it writes
    package: ClassVar[str | None] = None  # the optional PyPI package it needs (pip install 'appdgen[NAME]')

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


#: --encoder choices → encoder, the one registry.
ENCODERS: dict[str, Encoder] = {e.name: e for e in (OpenCVEncoder(), FpngEncoder())}
#: The default: the encoder every install has (fpng is an optional extra, and a build's bytes must not depend on
#: which extras a machine has).
DEFAULT_ENCODER = "opencv"
#: What builds and plans from before --encoder wrote (their build.json/plan.json name none): OpenCV's PNG, whatever
#: DEFAULT_ENCODER becomes.
LEGACY_ENCODER = "opencv"


def get_encoder(name: str, channels: int = 3) -> Encoder:
    """The encoder `name`, installed here and able to write `channels`; AppdgenError naming --encoder otherwise."""
    encoder = ENCODERS.get(name)
    if encoder is None:
        raise AppdgenError(f"--encoder {name!r}: expected one of {', '.join(ENCODERS)}")
    if not encoder.available():
        raise AppdgenError(f"--encoder {name}: needs the {encoder.package} package "
                           f"(pip install 'appdgen[{encoder.package}]')")
    if channels not in encoder.channels:
        raise AppdgenError(f"--encoder {name}: writes {'colour' if encoder.channels == (3,) else 'grey'} images "
                           f"only, not --channels {channels} (use --encoder {DEFAULT_ENCODER})")
    return encoder
