"""`predict`: APPD per image of a sequence, a running median, and a recalibrate verdict."""
from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from train import checkpoint, runtime
from appdgen.dataset.layout import FORMATS
from appdgen.dataset.sources import IMAGE_SUFFIXES
from train.errors import TrainError
from train.model import AppdNet

Preprocess = Callable[[np.ndarray, str], np.ndarray]
#: What a folder given to predict is listed for: raw camera images, and images as a build encodes them (.npy too).
IMAGES = frozenset((*IMAGE_SUFFIXES, *FORMATS.values()))


@dataclass(frozen=True)
class Prediction:
    """One image's predicted APPD (% of diagonal), the running median up to it, and the verdict."""

    path: str
    appd_pct: float
    running_median: float
    recalibrate: bool


def list_images(inputs: list[str]) -> list[Path]:
    """Files as given, folders expanded to their images sorted by name (the sequence order)."""
    paths: list[Path] = []
    for item in map(Path, inputs):
        if item.is_dir():
            paths += sorted(p for p in item.iterdir() if p.suffix.lower() in IMAGES)
        elif item.is_file():
            paths.append(item)
        else:
            raise TrainError(f"{item}: no such image or folder")
    if not paths:
        raise TrainError(f"no images found in {', '.join(inputs)}")
    return paths


def read_image(path: Path) -> np.ndarray:
    """H×W×3 uint8 in OpenCV's BGR order (.npy taken as stored, like the shards)."""
    if path.suffix.lower() == FORMATS["npy"]:
        img = np.load(path, allow_pickle=False)
    else:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None or img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise TrainError(f"{path}: not a readable 3-channel 8-bit image")
    return img


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


def crop_rule(ckpt: dict, ckpt_path: str, max_fov: float | None) -> dict:
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
        raise TrainError(f"--calib needs appdgen's formats/maps/render modules, which are missing here ({exc}); "
                         "rectify the images with `appdgen` first and predict without --calib") from None
    calib = load(calib_path, camera)
    rect = rectify(calib, size, max_fov=rule["max_fov"])
    interp = {"interp": rule["interp"]} if rule.get("interp") else {}  # unrecorded: remap_image's default

    def prep(img: np.ndarray, where: str) -> np.ndarray:
        if (img.shape[1], img.shape[0]) != tuple(calib.size):
            raise TrainError(f"{where}: raw image is {img.shape[1]}x{img.shape[0]} but {calib_path} "
                             f"describes a {calib.width}x{calib.height} camera")
        return remap_image(img, rect, **interp)
    return prep


def batches(paths: list[Path], prep: Preprocess, batch: int) -> Iterator[tuple[list[Path], torch.Tensor]]:
    """(paths, uint8 N×3×H×W) chunks of the sequence, preprocessed."""
    for i in range(0, len(paths), batch):
        chunk = paths[i:i + batch]
        imgs = [prep(read_image(p), str(p)) for p in chunk]
        yield chunk, torch.from_numpy(np.stack(imgs).transpose(0, 3, 1, 2).copy())


@torch.no_grad()
def run_model(model: AppdNet, images: torch.Tensor, device: torch.device) -> list[float]:
    """Predicted APPD (% of diagonal) per image, fp32 (deployment numbers should not depend on autocast)."""
    x = images.to(device).float().div_(255.0).contiguous(memory_format=torch.channels_last)
    return model(x).float().cpu().tolist()


def running_verdicts(paths: list[Path], values: list[float], window: int, threshold: float) -> list[Prediction]:
    """Median of the last `window` predictions and 'recalibrate' when it exceeds threshold (APPD %)."""
    recent: deque[float] = deque(maxlen=max(1, window))
    out = []
    for path, v in zip(paths, values):
        recent.append(v)
        med = statistics.median(recent)
        out.append(Prediction(str(path), v, med, med > threshold))
    return out


def predict(ckpt_path: str, inputs: list[str], calib: str | None = None, camera: str | None = None,
            threshold: float = 1.0, window: int = 9, batch: int = 32, resize: bool = False,
            device: str = "auto", max_fov: float | None = None) -> list[Prediction]:
    """Predictions over a sequence of images, in order (max_fov: degrees, only for a checkpoint without one)."""
    dev = runtime.pick_device(device)
    runtime.setup_threads(dev)
    ckpt = checkpoint.load(ckpt_path)
    if max_fov is not None and not calib:
        raise TrainError("--max-fov applies to rectifying raw images: it needs --calib")
    rule = crop_rule(ckpt, ckpt_path, max_fov)
    model = checkpoint.build_model(ckpt).to(dev).to(memory_format=torch.channels_last)
    size = (model.cfg.width, model.cfg.height)
    prep = rectifier(calib, camera, size, rule) if calib else size_check(size, resize)
    paths = list_images(inputs)
    values: list[float] = []
    for _, images in batches(paths, prep, batch):
        values += run_model(model, images, dev)
    return running_verdicts(paths, values, window, threshold)
