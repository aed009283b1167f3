"""Frames written as a robot's recording: a ROS 1 bag, a ROS 2 bag (mcap or sqlite3) or a video, through the
libraries' own writers (rosbags, PyAV), so that a build or predict on a recording runs without outside data."""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from appdgen.errors import AppdgenError

#: synth --as choices → what is written: a ROS 1 .bag, a ROS 2 bag folder (mcap / sqlite3 storage), an mp4 video.
KINDS = ("bag", "mcap", "db3", "video")
DEFAULT_TOPIC = "/cam0/image_raw"
FRAME_PERIOD_NS = 100_000_000  # 10 Hz, KITTI's rate
START_NS = 1_000_000_000_000_000_000  # an epoch time in 2001, as a recording's receive times are
#: Encodings whose pixels are converted from the BGR frame given; any other is written as the pixels are.
_CONVERSIONS = {"rgb8": cv2.COLOR_BGR2RGB}


def image_message(typestore, image: np.ndarray, stamp_ns: int, encoding: str | None = None,
                  compressed: str | None = None):
    """A sensor_msgs/Image (encoding: mono8 for grey, bgr8 for colour by default) or, with compressed 'jpeg' or
    'png', a CompressedImage, stamped stamp_ns."""
    header = typestore.types["std_msgs/msg/Header"](
        stamp=typestore.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id="cam0")
    if compressed is not None:
        ok, data = cv2.imencode(".jpg" if compressed == "jpeg" else ".png", image)
        if not ok:
            raise AppdgenError(f"cannot encode a frame as {compressed}")
        return typestore.types["sensor_msgs/msg/CompressedImage"](header=header, format=compressed,
                                                                  data=data.ravel())
    encoding = encoding or ("mono8" if image.ndim == 2 else "bgr8")
    conversion = _CONVERSIONS.get(encoding)
    pixels = np.ascontiguousarray(cv2.cvtColor(image, conversion) if conversion is not None else image)
    height, width = pixels.shape[:2]
    return typestore.types["sensor_msgs/msg/Image"](
        header=header, height=height, width=width, encoding=encoding, is_bigendian=0,
        step=pixels.strides[0], data=pixels.view(np.uint8).ravel())


def write_bag(path: Path, frames: Iterable[np.ndarray], kind: str = "bag", topic: str = DEFAULT_TOPIC,
              encoding: str | None = None, compressed: str | None = None, period_ns: int = FRAME_PERIOD_NS) -> int:
    """Write frames as one image topic of a ROS 1 bag (kind 'bag') or a ROS 2 bag folder ('mcap', 'db3'), at
    `period_ns` apart; returns the number of frames."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_HUMBLE)
    msgtype = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    ros1 = kind == "bag"
    if ros1:
        writer = Writer1(path)
    else:
        plugin = {"mcap": StoragePlugin.MCAP, "db3": StoragePlugin.SQLITE3}[kind]
        writer = Writer2(path, version=9, storage_plugin=plugin)
    count = 0
    with writer:
        connection = writer.add_connection(topic, msgtype, typestore=typestore)
        serialize = typestore.serialize_ros1 if ros1 else typestore.serialize_cdr
        for count, image in enumerate(frames, 1):
            stamp = START_NS + (count - 1) * period_ns
            message = image_message(typestore, image, stamp, encoding, compressed)
            writer.write(connection, stamp, serialize(message, msgtype))
    return count


def write_video(path: Path, frames: Iterable[np.ndarray], fps: int = 10, codec: str = "mpeg4") -> int:
    """Write BGR frames as a video (mp4 with MPEG-4 part 2 by default: in every FFmpeg build, high quality);
    returns the number of frames."""
    import av

    count = 0
    with av.open(str(path), "w") as container:
        stream = None
        for image in frames:
            count += 1
            if image.ndim == 2:
                image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
            if stream is None:
                stream = container.add_stream(codec, rate=fps)
                stream.width, stream.height, stream.pix_fmt = image.shape[1], image.shape[0], "yuv420p"
                stream.codec_context.options = {"qscale": "2"}
            for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="bgr24")):
                container.mux(packet)
        if stream is not None:
            for packet in stream.encode():
                container.mux(packet)
    return count


#: Where synth --as puts the recording in its output folder, per kind (KINDS).
RECORDING_NAMES = {"bag": "recording.bag", "mcap": "recording", "db3": "recording", "video": "recording.mp4"}


def recording_target(out: Path, kind: str) -> Path:
    """Where synth --as `kind` writes its recording in `out`; refused when something is there already."""
    target = out / RECORDING_NAMES[kind]
    if target.exists():
        raise AppdgenError(f"{target}: exists already (synth writes a new recording)")
    return target


def frames_as(paths: list[Path], out: Path, kind: str, mono: bool) -> Path:
    """synth's PNG frames rewritten as a recording of `kind` in `out` (RECORDING_NAMES), grey when mono, the PNGs
    then removed; kind 'png' keeps the PNGs (rewritten grey when mono). Returns what the frames are now."""
    def frames() -> Iterable[np.ndarray]:
        for path in paths:
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if mono else cv2.IMREAD_COLOR)
            if image is None:
                raise AppdgenError(f"{path}: not a readable image")
            yield image

    if kind == "png":
        if mono:
            from appdgen.dataset.images import write_image

            for path, image in zip(paths, frames(), strict=False):
                write_image(path, image)
        return out
    target = recording_target(out, kind)
    if kind == "video":
        write_video(target, frames())
    else:
        write_bag(target, frames(), kind=kind)
    for path in paths:
        path.unlink()
    return target
