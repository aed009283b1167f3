"""Raw images as a build's worker reads them: an image file (the last one decoded kept for the next sample) or a
frame of a recording (one pass per recording over a shard's frames). A raw image that passed the checks before the
build but no longer decodes is a RawImageError, which the build turns into its resume-or-rebuild hint."""
from __future__ import annotations

import functools
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from appdgen.errors import AppdgenError
from appdgen.sources.decode import as_channels, read_image
from appdgen.sources.frames import RawImage
from appdgen.sources.headers import check_complete


class RawImageError(AppdgenError):
    """A raw image that passed the checks before the build but does not decode in a worker."""


def read_raw(path: Path, channels: int = 3) -> np.ndarray:
    """A raw image for remapping (8-bit BGR, or grey for channels 1), refusing one cut short since the build began
    (it decodes grey)."""
    try:
        check_complete(path)
        return read_image(path, channels)
    except AppdgenError as exc:
        raise RawImageError(str(exc)) from None


def decoded(path: Path, channels: int = 3) -> np.ndarray:
    """A raw image, the last one a worker decoded kept for the next sample (consecutive samples share an image, and
    the next shard usually starts with the image the last one ended with); a file changed since is read anew."""
    try:
        stat = path.stat()
    except OSError:
        return read_raw(path, channels)  # names the file in its error
    return _decoded_version(path, stat.st_mtime_ns, stat.st_size, channels)


@functools.lru_cache(maxsize=1)
def _decoded_version(path: Path, mtime_ns: int, size: int, channels: int = 3) -> np.ndarray:
    """read_raw of one version of a file (the cache key)."""
    return read_raw(path, channels)


def forget_decoded() -> None:
    """Drop the raw image decoded() keeps (for a caller that changed how files decode, e.g. a test)."""
    _decoded_version.cache_clear()


class RawReader:
    """The raw images of one shard's samples: files through decoded(), frames of recordings through one
    recordings.FrameReader over the shard's frames (imported only for them: a build from files never loads it)."""

    def __init__(self, images: Iterable[RawImage]) -> None:
        frames = [image.frame for image in images if image.frame is not None]
        self._frames = None
        if frames:
            from appdgen.sources.recordings import FrameReader

            self._frames = FrameReader(frames)

    def read(self, image: RawImage, channels: int) -> np.ndarray:
        """The raw image of a sample with `channels` (1 grey, 3 BGR): a frame from the shard's reader, else the
        file; RawImageError naming it when it does not decode."""
        if image.frame is None:
            return decoded(image.path, channels)
        try:
            return as_channels(self._frames.read(image.frame), channels)
        except AppdgenError as exc:
            raise RawImageError(str(exc)) from None

    def close(self) -> None:
        """End the open pass over a recording (closes its file)."""
        if self._frames is not None:
            self._frames.close()
