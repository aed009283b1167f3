"""ROS 1 and ROS 2 bags (.bag, .db3, .mcap, ROS 2 bag folders) through rosbags: image topics, a topic's frame
index, and its sensor_msgs/Image or CompressedImage messages decoded to 8-bit images."""
from __future__ import annotations

import functools
import io
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from appdgen.errors import AppdgenError
from appdgen.sources.decode import decode_bytes, to_8bit
from appdgen.sources.frames import Frame, Index
from appdgen.sources.headers import ImageHeader, header_problem, stream_header, truncation

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
#: sensor_msgs/Image encodings read → (dtype, channels in the message, OpenCV conversion to grey/BGR or None).
#: OpenCV names a Bayer pattern by its second row's first two pixels: ROS's rggb is OpenCV's BG (as cv_bridge).
ENCODINGS: dict[str, tuple[str, int, int | None]] = {
    "mono8": ("u1", 1, None), "8UC1": ("u1", 1, None), "mono16": ("u2", 1, None), "16UC1": ("u2", 1, None),
    "bgr8": ("u1", 3, None), "8UC3": ("u1", 3, None), "rgb8": ("u1", 3, cv2.COLOR_RGB2BGR),
    "bgra8": ("u1", 4, cv2.COLOR_BGRA2BGR), "rgba8": ("u1", 4, cv2.COLOR_RGBA2BGR),
    "bayer_rggb8": ("u1", 1, cv2.COLOR_BayerBG2BGR), "bayer_bggr8": ("u1", 1, cv2.COLOR_BayerRG2BGR),
    "bayer_gbrg8": ("u1", 1, cv2.COLOR_BayerGR2BGR), "bayer_grbg8": ("u1", 1, cv2.COLOR_BayerGB2BGR),
}


def _rosbags():
    """rosbags' AnyReader and a default typestore (for ROS 2 files without embedded message definitions)."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise AppdgenError("reading ROS bags needs the 'ros' extra: pip install 'appdgen[ros]' (rosbags)") from None
    return AnyReader, get_typestore(Stores.ROS2_HUMBLE)


@contextmanager
def _reading(path: Path):
    """Turn rosbags' (and its storage libraries') errors while reading into one AppdgenError naming the bag."""
    try:
        yield
    except AppdgenError:
        raise
    except Exception as exc:  # noqa: BLE001 - a truncated file fails in rosbags, sqlite, struct or lz4 alike
        raise AppdgenError(f"{path}: cannot read bag ({type(exc).__name__}: {exc})") from None


@contextmanager
def open_bag(path: Path):
    """An open rosbags AnyReader on one bag."""
    any_reader, typestore = _rosbags()
    with _reading(path), any_reader([path], default_typestore=typestore) as reader:
        yield reader


def image_topics(path: Path) -> list[str]:
    """The bag's topics of sensor_msgs/Image or CompressedImage, sorted."""
    with open_bag(path) as reader:
        return sorted({c.topic for c in reader.connections if c.msgtype in (IMAGE, COMPRESSED)})


def _messages(reader, topic: str, start: int | None = None, stop: int | None = None) -> Iterator[tuple]:
    """(connection, timestamp ns, repeat, raw bytes) of a topic's messages in time order (repeat: earlier ones of
    the same timestamp since `start`)."""
    connections = [c for c in reader.connections if c.topic == topic]
    previous, repeat = None, 0
    for connection, timestamp, raw in reader.messages(connections, start=start, stop=stop):
        repeat = repeat + 1 if timestamp == previous else 0
        previous = timestamp
        yield connection, timestamp, repeat, raw


def index(path: Path, source: str, topic: str, size: tuple[int, int] | None, skip_bad: bool) -> tuple[Index, list]:
    """A topic's frames (bag timestamps), each one's size and encoding checked from its header; see
    recordings.index."""
    frames, dropped, mono = [], [], None
    with open_bag(path) as reader, _reading(path):
        for number, (connection, timestamp, repeat, raw) in enumerate(_messages(reader, topic)):
            frame = Frame(path, source, topic, timestamp, number, repeat)
            message = reader.deserialize(raw, connection.msgtype)
            header, problem = _message_header(message, connection.msgtype)
            if problem is None and size is not None:
                problem = header_problem(header, size)
            if problem is None and skip_bad and connection.msgtype == COMPRESSED:  # worth a decode only when asked
                problem = _undecodable(message, frame.where())
            if problem is None:
                frames.append(frame)
                mono = header.channels == 1 if mono is None else mono
            elif skip_bad:
                dropped.append({"path": frame.where(), "problem": problem})
            else:
                raise AppdgenError(f"{frame.where()}: {problem} (use --skip-bad to skip such frames)")
    if not frames:
        first = f": {dropped[0]['path']}: {dropped[0]['problem']}" if dropped else ""
        raise AppdgenError(f"{path}: topic {topic} has no usable frame{first}")
    return Index(frames, bool(mono), size or (header.width, header.height)), dropped


def _message_header(message, msgtype: str):
    """(ImageHeader of the decoded image: channels 1 grey or 3 colour, problem or None) of an image message."""
    if msgtype == IMAGE:
        if message.encoding not in ENCODINGS:
            return None, f"unknown encoding {message.encoding!r} (appdgen reads {', '.join(ENCODINGS)})"
        dtype, channels, conversion = ENCODINGS[message.encoding]
        need = message.width * channels * np.dtype(dtype).itemsize
        if message.step < need or len(message.data) < message.step * message.height:
            return None, f"{len(message.data)} data bytes, {message.height} rows of {message.step} expected"
        grey = channels == 1 and conversion is None
        return ImageHeader(message.width, message.height, 1 if grey else 3), None
    data = bytes(message.data)
    header = stream_header(io.BytesIO(data))
    problem = truncation(data)
    if header is None:
        return None, f"CompressedImage format {message.format!r} is not a readable PNG or JPEG"
    return ImageHeader(header.width, header.height, 1 if header.channels == 1 else 3), problem


def _undecodable(message, where: str) -> str | None:
    """Why a CompressedImage does not decode, or None (--skip-bad decodes each once in the parent, so a worker
    never meets one it would have to stop at)."""
    try:
        decode_message(message, COMPRESSED, where)
    except AppdgenError as exc:
        return str(exc).removeprefix(f"{where}: ")
    return None


def decode_message(message, msgtype: str, where: str) -> np.ndarray:
    """An Image or CompressedImage message as an 8-bit image: grey H×W for mono, BGR H×W×3 otherwise."""
    if msgtype == COMPRESSED:
        try:
            image = to_8bit(decode_bytes(bytes(message.data), where))
        except AppdgenError as exc:
            problem = str(exc).removeprefix(f"{where}: ")
            detail = "" if problem == "not a readable image" else f": {problem}"
            raise AppdgenError(f"{where}: undecodable {message.format or 'compressed'} image{detail}") from None
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR) if image.ndim == 3 and image.shape[2] == 4 else image
    dtype, channels, conversion = ENCODINGS[message.encoding]
    itemsize = np.dtype(dtype).itemsize
    rows = np.frombuffer(message.data, np.uint8)[:message.step * message.height].reshape(message.height, -1)
    order = ">" if message.is_bigendian else "<"
    pixels = np.ascontiguousarray(rows[:, :message.width * channels * itemsize]).view(order + dtype)
    image = to_8bit(pixels.reshape(message.height, message.width, channels).squeeze(2) if channels == 1
                    else pixels.reshape(message.height, message.width, channels))
    return cv2.cvtColor(image, conversion) if conversion is not None else image


def read_frames(path: Path, topic: str, first: Frame, last: Frame) -> Iterator[tuple[tuple, Callable]]:
    """See recordings.read_frames: one ranged read of the bag (rosbags seeks by its index)."""
    with open_bag(path) as reader, _reading(path):
        start = first.timestamp_ns if first is not None else None
        stop = last.timestamp_ns + 1 if last is not None else None
        for connection, timestamp, repeat, raw in _messages(reader, topic, start, stop):
            where = f"{path}: topic {topic} at {timestamp} ns"
            yield (timestamp, repeat, None), functools.partial(_decoded, reader, connection.msgtype, raw, where)


def _decoded(reader, msgtype: str, raw: bytes, where: str) -> np.ndarray:
    """One message deserialized and decoded (errors name it)."""
    with _reading(Path(where)):
        return decode_message(reader.deserialize(raw, msgtype), msgtype, where)
