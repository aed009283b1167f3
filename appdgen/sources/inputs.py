"""What an --images spec names, resolved once for `build` and `fit --online`: the camera of the calibration file
that shot it, its reference calibration, and the raw images (files, or frames of recordings) with their splits."""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.calib.formats import calibration_topic, list_cameras, load
from appdgen.errors import AppdgenError
from appdgen.sources import recordings
from appdgen.sources.files import all_grey, check_images, kitti_camera, list_images
from appdgen.sources.frames import RawImage
from appdgen.sources.headers import image_size
from appdgen.sources.raw import RawReader
from appdgen.sources.recordings import FrameChoice

#: Every frame of a recording (the default choice).
EVERY_FRAME = FrameChoice()


@dataclass(frozen=True)
class Inputs:
    """The resolved inputs: camera name, reference calibration, raw images in order, the images skipped
    (--skip-bad), whether every source is grey, and the recordings' (source, sha256) (empty for image files)."""

    camera: str
    reference: Calibration
    images: tuple[RawImage, ...]
    skipped: list[dict] = field(default_factory=list)
    mono: bool = False
    recordings: tuple[tuple[str, str], ...] = ()


def resolve_inputs(spec: str, calib_path: str, camera: str | None = None, split_by: str = "none",
                   topic: str | None = None, choice: FrameChoice = EVERY_FRAME, skip_bad: bool = False,
                   check_grey: bool = True) -> Inputs:
    """The inputs an --images spec names (a folder, glob or list of images, or recordings) with the calibration
    file's camera for them; every image checked against the camera's size (check_grey: also whether all are grey)."""
    found = recordings.list_recordings(spec)
    if found:
        camera = choose_camera(calib_path, camera, recording=found[0], topic=topic)
        reference = load(Path(calib_path), camera=camera)
        frames = recordings.raw_images(found, spec, split_by, topic, calibration_topic(calib_path, camera), choice,
                                       reference.size, skip_bad)
        return Inputs(camera, reference, tuple(frames.images), frames.skipped, frames.mono, frames.recordings)
    if topic is not None or choice != FrameChoice():
        raise AppdgenError(f"--images {spec}: --topic/--every/--min-interval/--start/--end choose frames of "
                           "recordings (bags, videos), not image files")
    images = list_images(spec, split_by)
    camera = choose_camera(calib_path, camera, images)
    reference = load(Path(calib_path), camera=camera)
    images, skipped = check_images(images, reference.size, skip_bad)
    return Inputs(camera, reference, tuple(images), skipped, check_grey and all_grey(images))


def choose_camera(calib_path: str, camera: str | None, images: list[RawImage] = (), recording: Path | None = None,
                  topic: str | None = None) -> str:
    """--camera, else the file's only camera, else the one the inputs point at: for a recording the camera whose
    rostopic is --topic or one of the recording's image topics; for image files the KITTI image_0X folder, else the
    only camera of the images' size."""
    if camera is not None:
        return camera
    cameras = list_cameras(Path(calib_path))
    if len(cameras) == 1:
        return cameras[0]
    if recording is not None:
        return _camera_of_topic(calib_path, cameras, recording, topic)
    return _camera_of_images(calib_path, cameras, images)


def _camera_of_topic(calib_path: str, cameras: list[str], recording: Path, topic: str | None) -> str:
    """The one camera whose rostopic is --topic, else one of the recording's image topics."""
    wanted = {topic} if topic is not None else set(recordings.topics(recording))
    fitting = [c for c in cameras if calibration_topic(calib_path, c) in wanted]
    if len(fitting) == 1:
        return fitting[0]
    raise AppdgenError(f"{calib_path}: cameras {', '.join(fitting or cameras)}: choose one with --camera")


def _camera_of_images(calib_path: str, cameras: list[str], images: list[RawImage]) -> str:
    """The KITTI image_0X folder's camera, else the only camera whose size matches the first image."""
    named = kitti_camera(images)
    if named is not None and named in cameras:
        return named
    size = image_size(images[0].path)
    fitting = [c for c in cameras if load(Path(calib_path), camera=c).size == size]
    if len(fitting) == 1:
        return fitting[0]
    if not fitting:
        raise AppdgenError(f"{calib_path}: no camera ({', '.join(cameras)}) is {size[0]}x{size[1]} like "
                           f"{images[0].path}")
    raise AppdgenError(f"{calib_path}: cameras {', '.join(fitting)} fit the images; choose one with --camera")


def iter_images(images: list[RawImage], channels: int = 3) -> Iterator[np.ndarray]:
    """Every raw image decoded lazily in order as 8-bit images of `channels` (1: grey H×W, 3: BGR H×W×3): files one
    by one, frames of recordings in one pass per recording (raw.RawReader, the build's own reader, so the same rules
    and errors); AppdgenError naming the file on an unreadable or truncated one."""
    reader = RawReader(images)
    try:
        for image in images:
            yield reader.read(image, channels)
    finally:
        reader.close()


def read_images(images: list[RawImage], channels: int = 3) -> list[np.ndarray]:
    """Every raw image decoded in order (iter_images, held in memory)."""
    return list(iter_images(images, channels))
