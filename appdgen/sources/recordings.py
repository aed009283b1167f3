"""Recordings as image sources: ROS 1/ROS 2 bags and videos → an index of frames, chosen and read in order.

The parent indexes each recording once (topic, timestamp in ns, position in the stream); a worker then reads only
its shard's frames, in one pass over their time range (FrameReader), never the whole recording.
"""
from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from appdgen.errors import AppdgenError
from appdgen.sources.files import IMAGE_SUFFIXES, split_of
from appdgen.sources.frames import Frame, Index, RawImage

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
VIDEO_SUFFIXES = (".mp4", ".mkv", ".avi", ".mov", ".webm", ".m4v", ".mpg", ".mpeg", ".ts", ".mts")
ROS2_METADATA = "metadata.yaml"  # a ROS 2 bag folder holds it beside its .db3/.mcap files
#: --channels choices: auto follows the source (1 when every image is grey), else 1 (grey) or 3 (BGR).
CHANNELS = ("auto", "1", "3")
_HASH_BLOCK = 1 << 22
T = TypeVar("T")  # bytes hashed at a time (a recording may be larger than memory)


@dataclass(frozen=True)
class FrameChoice:
    """Which frames of a recording to keep: a time window (seconds from its first frame), every Nth, at least
    `min_interval` seconds apart."""

    every: int = 1
    min_interval: float = 0.0
    start: float | None = None
    end: float | None = None

    def __post_init__(self) -> None:
        if self.every < 1:
            raise AppdgenError(f"--every {self.every}: must be at least 1")
        if self.min_interval < 0:
            raise AppdgenError(f"--min-interval {self.min_interval:g}: must not be negative")
        if self.start is not None and self.end is not None and self.end <= self.start:
            raise AppdgenError(f"--end {self.end:g} must be after --start {self.start:g}")

    def apply(self, frames: list[Frame]) -> list[Frame]:
        """The kept frames, in order: the window first, then every Nth of it, then the minimum interval."""
        return [frame for frame, _ in self.select((f, None) for f in frames)]

    def select(self, items: Iterable[tuple[Frame, T]]) -> Iterator[tuple[Frame, T]]:
        """The kept (frame, anything) pairs of a stream in time order, as apply; stops reading at --end."""
        first = last = None
        position = 0
        gap = round(self.min_interval * 1e9)
        for item in items:
            time = item[0].timestamp_ns
            first = time if first is None else first
            if self.end is not None and time >= first + round(self.end * 1e9):
                return
            if self.start is not None and time < first + round(self.start * 1e9):
                continue
            position += 1
            if (position - 1) % self.every or (last is not None and time - last < gap):
                continue
            last = time
            yield item


def resolve_channels(choice: str, mono: bool) -> int:
    """The samples' channels for a --channels choice and whether every source image is grey."""
    return (1 if mono else 3) if choice == "auto" else int(choice)


def is_recording(path: Path) -> bool:
    """Whether a path is a bag file, a ROS 2 bag folder or a video file (by its name)."""
    if path.is_dir():
        return (path / ROS2_METADATA).is_file()
    return path.suffix.lower() in BAG_SUFFIXES + VIDEO_SUFFIXES


def is_video(path: Path) -> bool:
    """Whether a recording is a video (else a bag)."""
    return not path.is_dir() and path.suffix.lower() in VIDEO_SUFFIXES


def list_recordings(spec: str) -> list[Path] | None:
    """The recordings an --images spec names (one recording, or a folder of recordings and no image files, sorted
    by name), or None when it names image files instead (a folder of images keeps a stray video out, as before)."""
    path = Path(spec)
    if is_recording(path):
        if not path.exists():
            raise AppdgenError(f"{spec}: no such recording")
        return [path]
    if not path.is_dir():
        return None
    found = sorted(p for p in path.iterdir() if is_recording(p) and not p.name.startswith("."))
    if not found or any(p.suffix.lower() in IMAGE_SUFFIXES and p.is_file() for p in path.rglob("*")):
        return None
    return found


def recording_hash(path: Path) -> str:
    """SHA-256 (hex) of a recording's bytes: a file, or a ROS 2 folder's files in name order, read in blocks."""
    digest = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    try:
        for file in files:
            digest.update(f"{file.relative_to(path).as_posix() if path.is_dir() else ''}\0".encode())
            with open(file, "rb") as handle:
                while block := handle.read(_HASH_BLOCK):
                    digest.update(block)
    except OSError as exc:
        raise AppdgenError(f"{path}: cannot read recording ({exc.strerror or exc})") from None
    return digest.hexdigest()


def _module(path: Path):
    """The reader module for a recording (bags or video), imported on first use (each needs its extra)."""
    if is_video(path):
        from appdgen.sources import video
        return video
    from appdgen.sources import bags
    return bags


def topics(path: Path) -> list[str]:
    """The image topics of a recording ([""] for a video)."""
    return _module(path).image_topics(path)


def choose_topic(path: Path, topic: str | None, calibrated: str | None) -> str:
    """--topic, else the calibration's rostopic (or its /compressed twin, as image_transport records it), else the
    only image topic; errors list the image topics."""
    found = topics(path)
    if is_video(path):
        return ""
    listed = ", ".join(found) or "none"
    if topic is not None:
        if topic not in found:
            raise AppdgenError(f"{path}: no image topic {topic} (image topics: {listed})")
        return topic
    if calibrated is not None:
        if calibrated not in found and f"{calibrated}/compressed" in found:  # image_transport's JPEG topic
            return f"{calibrated}/compressed"
        if calibrated not in found:
            raise AppdgenError(f"{path}: the calibration's rostopic {calibrated} is not an image topic of the bag "
                               f"(image topics: {listed}); choose one with --topic")
        return calibrated
    if len(found) == 1:
        return found[0]
    if not found:
        raise AppdgenError(f"{path}: no sensor_msgs/Image or CompressedImage topic")
    raise AppdgenError(f"{path}: several image topics ({listed}); choose one with --topic")


def index(path: Path, source: str, topic: str, size: tuple[int, int] | None, skip_bad: bool) -> tuple[Index, list]:
    """The frames of one topic (video: its frames) with their size checked against `size` (w, h) when given;
    frames that fail are refused (the first named) or, with skip_bad, dropped and returned as {"path", "problem"}."""
    return _module(path).index(path, source, topic, size, skip_bad)


def read_frames(path: Path, topic: str, first: Frame | None, last: Frame | None
                ) -> Iterator[tuple[tuple, Callable[[], np.ndarray]]]:
    """(identity, decode) of each frame from `first` to `last` (None: the recording's first, last) in stream
    order: identity as _identity, decode gives the 8-bit image (grey H×W or BGR H×W×3) when called (frames a
    shard skips are never decoded)."""
    return _module(path).read_frames(path, topic, first, last)


def stream(path: Path, topic: str, choice: FrameChoice) -> Iterator[tuple[Frame, Callable[[], np.ndarray]]]:
    """The chosen frames of one topic (video: of the video) and their decoders, in one pass, nothing indexed
    first (memory flat over an hour-long recording: predict)."""
    numbered = ((Frame(path, path.as_posix(), topic, ident[0], number, ident[1], ident[2]), decode)
                for number, (ident, decode) in enumerate(read_frames(path, topic, None, None)))
    return choice.select(numbered)


def _identity(frame: Frame) -> tuple:
    """What a reader matches a frame by."""
    return frame.timestamp_ns, frame.repeat, frame.pts


class FrameReader:
    """A worker's frames of one shard: asked in stream order, decoded in one pass per recording over the range
    of frames the shard needs (a frame asked again is served from the last one)."""

    def __init__(self, frames: list[Frame]) -> None:
        self._last: dict[tuple, Frame] = {}
        for frame in frames:  # the shard's last frame of each recording bounds its pass
            self._last[(frame.recording, frame.topic)] = frame
        self._stream: Iterator | None = None
        self._key: tuple | None = None
        self._held: tuple[tuple, np.ndarray] | None = None

    def read(self, frame: Frame) -> np.ndarray:
        """The decoded image of `frame` (8-bit grey H×W or BGR H×W×3); AppdgenError naming it when missing."""
        key = (frame.recording, frame.topic)
        if self._held is not None and self._key == key and self._held[0] == _identity(frame):
            return self._held[1]
        if self._key != key or self._stream is None:
            self._open(frame)
        for attempt in range(2):
            for ident, decode in self._stream:
                if ident == _identity(frame):
                    self._held = (ident, decode())
                    return self._held[1]
            if attempt == 0:  # asked for a frame before the stream's position: read again from it
                self._open(frame)
        raise AppdgenError(f"{frame.where()}: frame not found (the recording changed since it was indexed?)")

    def _open(self, frame: Frame) -> None:
        """Start a pass from `frame` to the shard's last frame of its recording."""
        if self._stream is not None:
            self._stream.close()
        key = (frame.recording, frame.topic)
        self._key, self._held = key, None
        self._stream = read_frames(frame.recording, frame.topic, frame, self._last[key])

    def close(self) -> None:
        """End the open pass (closes its file)."""
        if self._stream is not None:
            self._stream.close()
            self._stream = None


@dataclass(frozen=True)
class Frames:
    """The raw images an --images spec of recordings gives: frames as RawImage, whether all are mono, the frames
    skipped ({"path", "problem"}) and the recordings as (source, sha256)."""

    images: list
    mono: bool
    skipped: list[dict]
    recordings: tuple[tuple[str, str], ...]


def raw_images(recordings: list[Path], spec: str, split_by: str, topic: str | None, calibrated: str | None,
               choice: FrameChoice, size: tuple[int, int], skip_bad: bool) -> Frames:
    """The chosen frames of every recording, in order, each a RawImage (split: the recording's name for
    --split-by recording; calibrated: the calibration's rostopic)."""
    images, mono, skipped, hashes = [], True, [], []
    folder = None if is_recording(Path(spec)) else Path(spec)  # a folder of recordings: sources relative to it
    for path in recordings:
        source = path.relative_to(folder).as_posix() if folder is not None else spec
        chosen = choose_topic(path, topic, calibrated)
        found, dropped = index(path, source, chosen, size, skip_bad)
        kept = choice.apply(found.frames)
        if not kept:
            where = f" topic {chosen}" if chosen else ""
            raise AppdgenError(f"{path}{where}: no frames left after --start/--end/--every/--min-interval")
        split = path.name if split_by == "recording" else split_of(Path(source), split_by)
        images += [RawImage(path, frame.name, split, frame) for frame in kept]
        skipped += dropped
        mono = mono and found.mono
        hashes.append((source, recording_hash(path)))
    return Frames(images, mono, skipped, tuple(hashes))
