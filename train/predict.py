"""`predict`: APPD per image of a sequence (images, or the frames of a bag or video), a running median, and a
recalibrate verdict, streamed batch by batch."""
from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import cv2
import numpy as np
import torch

from appdgen.detect import DEFAULT_THRESHOLD_PCT
from appdgen.errors import AppdgenError
from appdgen.sources.decode import as_channels, read_image
from appdgen.sources.files import IMAGE_SUFFIXES, list_images
from appdgen.sources.frames import RawImage
from train import checkpoint, runtime
from train.errors import TrainError
from train.inference import predict

Preprocess = Callable[[np.ndarray, str], np.ndarray]
#: One image of the sequence: its name, its timestamp (ns, frames of recordings) or None, and its decoder.
Item = tuple[str, "int | None", Callable[[], np.ndarray]]


@dataclass(frozen=True)
class Prediction:
    """One image's predicted APPD (% of diagonal), the running median up to it, and the verdict."""

    path: str
    appd_pct: float
    running_median: float
    recalibrate: bool
    timestamp_ns: int | None = field(default=None, kw_only=True)  # frames of a recording: when it was taken


def image_files(inputs: list[str]) -> list[RawImage]:
    """The images the inputs name, in order: an image file as itself, else what appdgen.sources.files.list_images
    reads (a folder, recursively, a glob or a list file; its one-line errors)."""
    found: list[RawImage] = []
    for spec in inputs:
        path = Path(spec)
        is_image = path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES
        found += [RawImage(path, path.name, "none")] if is_image else list_images(spec)
    return found


@dataclass(frozen=True)
class PredictFrames:
    """Which frames of a recording predict reads (as build's --topic, --every, --min-interval, --start, --end),
    and whether undecodable frames are skipped (counted in `skipped`) instead of refused."""

    topic: str | None = None
    every: int = 1
    min_interval: float = 0.0
    start: float | None = None
    end: float | None = None
    skip_bad: bool = False
    skipped: list = field(default_factory=list, compare=False)


def sequence(inputs: list[str], frames: PredictFrames, calib: str | None, camera: str | None) -> Iterator[Item]:
    """The images in order: a recording's chosen frames, streamed (the topic as build chooses it), else the
    files and folders' images."""
    from appdgen.sources.recordings import is_recording

    if not any(is_recording(Path(i)) for i in inputs):
        yield from checked(((str(i.path), None, partial(read_image, i.path)) for i in image_files(inputs)), frames)
        return
    if len(inputs) != 1:
        raise TrainError(f"predict reads one recording at a time, got {', '.join(inputs)}")
    yield from checked(recording_items(Path(inputs[0]), frames, calib, camera), frames)


def recording_items(path: Path, frames: PredictFrames, calib: str | None, camera: str | None) -> Iterator[Item]:
    """The chosen frames of a bag or video as items, in one pass (memory flat over hour-long recordings)."""
    from appdgen.calib.formats import calibration_topic
    from appdgen.sources.recordings import FrameChoice, choose_topic, stream

    if not path.exists():
        raise TrainError(f"{path}: no such recording")
    choice = FrameChoice(frames.every, frames.min_interval, frames.start, frames.end)
    topic = choose_topic(path, frames.topic, calibration_topic(calib, camera) if calib else None)
    for frame, decode in stream(path, topic, choice):
        yield frame.name, frame.timestamp_ns, decode


def checked(items: Iterable[Item], frames: PredictFrames) -> Iterator[Item]:
    """The items as they are; with --skip-bad each decoded now, and an undecodable one (a corrupt JPEG body, an
    unreadable file) counted in frames.skipped instead of refused."""
    for name, stamp, decode in items:
        if not frames.skip_bad:
            yield name, stamp, decode
            continue
        try:
            image = decode()
        except AppdgenError as exc:
            frames.skipped.append(str(exc))
            continue
        yield name, stamp, partial(np.asarray, image)


def size_check(size: tuple[int, int], resize: bool) -> Preprocess:
    """Images must already be rectified at the network size (w, h); --resize rescales them instead."""
    def prep(img: np.ndarray, where: str) -> np.ndarray:
        if (img.shape[1], img.shape[0]) == size:
            return img
        if not resize:
            raise TrainError(f"{where}: image is {img.shape[1]}x{img.shape[0]} but the network takes "
                             f"{size[0]}x{size[1]}; pass --calib to rectify raw images, or --resize")
        return cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    return prep


def rectify_rule(ckpt: dict, ckpt_path: str, max_fov: float | None) -> dict:
    """The rectification rule (max_fov degrees, interp) for raw images: the one the detector was trained with.

    --max-fov fills in a checkpoint that does not record its rule; one that contradicts the recorded rule is
    refused: another field of view shows the network images at another scale than it learned, so its APPD
    (% of the diagonal) would be meaningless.
    """
    trained = checkpoint.rectify_rule(ckpt)
    if trained is None:
        return {"max_fov": max_fov, "interp": None}
    if max_fov is not None and max_fov != trained.get("max_fov"):
        raise TrainError(f"--max-fov {max_fov:g}: {ckpt_path} was trained on "
                         f"{checkpoint.describe_fov(trained.get('max_fov'))}; omit --max-fov to rectify as it was "
                         "trained")
    return dict(trained)


def rectifier(calib_path: str, camera: str | None, size: tuple[int, int], rule: dict) -> Preprocess:
    """Rectify raw images with a calibration (cropped by the training rule, rescaled to size) as a deployed robot
    would."""
    try:
        from appdgen.calib.formats import load
        from appdgen.geometry.maps import rectify
        from appdgen.geometry.remap import remap_image
    except ImportError as exc:
        raise TrainError(f"--calib needs appdgen's calibration, maps and remap modules, which are missing here "
                         f"({exc}); rectify the images with `appdgen` first and predict without --calib") from None
    calib = load(calib_path, camera)
    rect = rectify(calib, size, max_fov=rule["max_fov"])
    interp = {"interp": rule["interp"]} if rule.get("interp") else {}  # unrecorded: remap_image's default

    def prep(img: np.ndarray, where: str) -> np.ndarray:
        if (img.shape[1], img.shape[0]) != tuple(calib.size):
            raise TrainError(f"{where}: raw image is {img.shape[1]}x{img.shape[0]} but {calib_path} "
                             f"describes a {calib.width}x{calib.height} camera")
        return remap_image(img, rect, **interp)
    return prep


def batches(items: Iterable[Item], prep: Preprocess, batch: int, channels: int = 3) -> Iterator[dict]:
    """Batches of the sequence ({"items": its items, "image": uint8 N×C×H×W}), decoded with the network's channels
    and preprocessed (each item as it comes: a recording's decoder holds its file open only until the next frame)."""
    chunk: list[Item] = []
    imgs: list[np.ndarray] = []
    for item in items:
        name, _, decode = item
        chunk.append(item)
        img = prep(as_channels(decode(), channels), name)
        imgs.append(img.reshape(*img.shape[:2], -1))
        if len(chunk) == batch:
            yield {"items": chunk, "image": torch.from_numpy(np.stack(imgs).transpose(0, 3, 1, 2).copy())}
            chunk, imgs = [], []
    if chunk:
        yield {"items": chunk, "image": torch.from_numpy(np.stack(imgs).transpose(0, 3, 1, 2).copy())}


class RunningVerdict:
    """The running median of the last `window` predictions, and 'recalibrate' when it exceeds threshold (APPD %)."""

    def __init__(self, window: int, threshold: float) -> None:
        self.recent: deque[float] = deque(maxlen=max(1, window))
        self.threshold = threshold

    def add(self, path: str, value: float, timestamp_ns: int | None = None) -> Prediction:
        """The prediction of the next image with the verdict up to it."""
        self.recent.append(value)
        med = statistics.median(self.recent)
        return Prediction(path, value, med, med > self.threshold, timestamp_ns=timestamp_ns)


def trained_target(ckpt_path: str) -> str:
    """What a checkpoint's network predicts (layout.TARGETS: appd, or bend), for predict's summary."""
    return checkpoint.target(checkpoint.load(ckpt_path))


def predict_stream(ckpt_path: str, inputs: list[str], calib: str | None = None, camera: str | None = None,
                   threshold: float = DEFAULT_THRESHOLD_PCT, window: int = 9, batch: int = 32, resize: bool = False,
                   device: str = "auto", max_fov: float | None = None, frames: PredictFrames | None = None
                   ) -> Iterator[Prediction]:
    """predict's predictions as each batch is done (a recording is read once, frame by frame)."""
    dev = runtime.pick_device(device)
    runtime.setup_threads(dev)
    ckpt = checkpoint.load(ckpt_path)
    if max_fov is not None and not calib:
        raise TrainError("--max-fov applies to rectifying raw images: it needs --calib")
    rule = rectify_rule(ckpt, ckpt_path, max_fov)
    model = checkpoint.build_model(ckpt).to(dev).to(memory_format=torch.channels_last)
    size = (model.cfg.width, model.cfg.height)
    prep = rectifier(calib, camera, size, rule) if calib else size_check(size, resize)
    verdicts = RunningVerdict(window, threshold)
    found = False
    chunks = batches(sequence(inputs, frames or PredictFrames(), calib, camera), prep, batch, model.cfg.in_channels)
    for chunk, out in predict(model, chunks, dev):  # fp32: deployment numbers should not depend on autocast
        found = True
        for (name, stamp, _), value in zip(chunk["items"], out.cpu().tolist(), strict=True):
            yield verdicts.add(name, value, stamp)
    if not found:
        raise TrainError(f"no frames chosen in {', '.join(inputs)}")
