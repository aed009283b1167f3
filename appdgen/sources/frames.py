"""The value types a source gives: a raw image (a file, or a frame of a recording), a recording's frame and a
recording's index of frames. Every source module and the build import them; they import nothing of appdgen."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RawImage:
    """One raw image: its path, the path as recorded in the index, and its split name; for a frame of a
    recording (bag, video) the recording's path and the frame."""

    path: Path
    name: str
    split: str
    frame: Frame | None = None


@dataclass(frozen=True)
class Frame:
    """One frame of a recording: where it lies (topic; timestamp ns; its number in the topic or video, from 0)
    and how a reader finds it again (repeat: earlier frames of the same timestamp; pts: a video's own clock)."""

    recording: Path
    source: str  # the recording as given (labels.parquet's `source`)
    topic: str  # "" for a video
    timestamp_ns: int
    number: int
    repeat: int = 0
    pts: int | None = None

    @property
    def name(self) -> str:
        """The frame's raw_path: SOURCE/TOPIC/TIMESTAMP_NS for a bag, SOURCE/NUMBER for a video (whose dirname is
        the recording, the unit a trainer's holdout keeps whole)."""
        if self.pts is None:
            return f"{self.source}/{self.topic.strip('/')}/{self.timestamp_ns}"
        return f"{self.source}/{self.number:06d}"

    def where(self) -> str:
        """The frame in an error message: file, topic and timestamp (or frame number)."""
        if self.pts is None:
            return f"{self.recording}: topic {self.topic} at {self.timestamp_ns} ns"
        return f"{self.recording}: frame {self.number} ({self.timestamp_ns} ns)"


@dataclass(frozen=True)
class Index:
    """A recording's frames on one topic, and what they are: mono or colour, (width, height) in pixels."""

    frames: list[Frame]
    mono: bool
    size: tuple[int, int]
