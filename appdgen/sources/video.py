"""Video files (mp4, mkv, avi, mov, …) through PyAV: the frame index of the first video stream (presentation
order, from the packets, nothing decoded) and its frames decoded from the keyframe before a shard's first one."""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path

from appdgen.errors import AppdgenError
from appdgen.sources.frames import Frame, Index
from appdgen.sources.headers import ImageHeader, header_problem


def _av():
    """The PyAV module (the 'video' extra)."""
    try:
        import av
    except ImportError:
        raise AppdgenError("reading videos needs the 'video' extra: pip install 'appdgen[video]' (PyAV)") from None
    return av


@contextmanager
def open_video(path: Path):
    """(container, its first video stream), FFmpeg's errors turned into one AppdgenError naming the file."""
    av = _av()
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise AppdgenError(f"{path}: no video stream")
            stream = container.streams.video[0]
            stream.codec_context.thread_count = 1  # the build decides parallelism (one worker per core)
            yield container, stream
    except (av.FFmpegError, OSError, ValueError) as exc:
        raise AppdgenError(f"{path}: cannot read video ({exc})") from None


def image_topics(path: Path) -> list[str]:
    """A video has one image stream and no topics: [""] (checks it opens)."""
    with open_video(path):
        return [""]


def _ns(pts: int, time_base: Fraction) -> int:
    """A presentation timestamp in nanoseconds."""
    return int(pts * time_base * 1_000_000_000)


def index(path: Path, source: str, topic: str, size: tuple[int, int] | None, skip_bad: bool) -> tuple[Index, list]:
    """The video's frames in presentation order (pts of its packets); its size checked against `size`; see
    recordings.index (one size for the whole stream: skip_bad cannot help a video of the wrong size)."""
    with open_video(path) as (container, stream):
        header = ImageHeader(stream.codec_context.width, stream.codec_context.height,
                             1 if (stream.codec_context.pix_fmt or "").startswith("gray") else 3)
        problem = header_problem(header, size) if size is not None else None
        if problem:
            raise AppdgenError(f"{path}: {problem}")
        pts = sorted(p.pts for p in container.demux(stream) if p.pts is not None and p.size)
        base = stream.time_base
    if not pts:
        raise AppdgenError(f"{path}: the video stream holds no frames")
    frames = [Frame(path, source, topic, _ns(p, base), number, 0, p) for number, p in enumerate(pts)]
    return Index(frames, header.channels == 1, header.size), []


def read_frames(path: Path, topic: str, first: Frame, last: Frame) -> Iterator[tuple[tuple, Callable]]:
    """See recordings.read_frames: seek to the keyframe at or before `first`, decode on to `last`."""
    av = _av()
    with open_video(path) as (container, stream):
        mono = (stream.codec_context.pix_fmt or "").startswith("gray")
        try:
            if first is not None:
                container.seek(first.pts, stream=stream, backward=True, any_frame=False)
            for frame in container.decode(stream):
                if frame.pts is None or (first is not None and frame.pts < first.pts):
                    continue
                if last is not None and frame.pts > last.pts:
                    return
                yield (_ns(frame.pts, stream.time_base), 0, frame.pts), _converter(frame, mono)
        except av.FFmpegError as exc:
            raise AppdgenError(f"{path}: cannot decode the video ({exc})") from None


def _converter(frame, mono: bool) -> Callable:
    """The frame as an 8-bit grey (mono) or BGR array, when called."""
    return lambda: frame.to_ndarray(format="gray" if mono else "bgr24")
