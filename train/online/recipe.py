"""What every pair of an online run is drawn with (the reference camera, output size and sampling options) and
the raw frames it draws from, decoded once into memory."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.geometry.appd import px_to_pct
from appdgen.geometry.crop import check_output_size, valid_region
from appdgen.geometry.remap import remap_image
from appdgen.sampling.options import SamplingOptions
from appdgen.sampling.sampler import target_px
from appdgen.sources.decode import read_image
from appdgen.sources.frames import RawImage
from appdgen.sources.inputs import read_images, resolve_inputs
from appdgen.sources.recordings import FrameChoice
from appdgen.util.sizes import parse_size
from train.online.options import OnlineOptions


@dataclass(frozen=True)
class PairRecipe:
    """The reference camera (and its id in the file), the output size (w, h) and the sampling options every pair
    is drawn with, and the target its label is (sampling.sampler.TARGETS: appd or bend)."""

    reference: Calibration
    camera: str
    size: tuple[int, int]
    sampling: SamplingOptions
    target: str = "appd"

    def sampler(self):
        """This process's labelling sampler (cached per options)."""
        return self.sampling.sampler(self.reference, self.size)

    def label(self, draw) -> float:
        """A draw's label (% of the raw diagonal): its APPD, or its bend, as `appdgen build` writes them."""
        return px_to_pct(target_px(self.sampler(), draw, self.target), self.reference)

    def render(self, raw: np.ndarray, draw) -> np.ndarray:
        """The cpu renderer: a raw frame through a draw's rectification, H×W×3 uint8, as build renders sample i."""
        return remap_image(raw, draw.rect, self.sampling.interp)


def open_recipe(o: OnlineOptions, target: str = "appd") -> tuple[PairRecipe, list[RawImage]]:
    """The calibration, size, sampling options (checked: reachable --appd-max), the target and the listed raw
    images; appdgen's one-line errors (AppdgenError, which the trainer's CLI prints as its own)."""
    choice = FrameChoice(o.every, o.min_interval, o.start, o.end)
    inputs = resolve_inputs(o.images, o.calib, o.camera, o.split_by, o.topic, choice, check_grey=False)
    reference, camera, images = inputs.reference, inputs.camera, list(inputs.images)
    size = check_output_size(reference, parse_size(o.size) or reference.size)
    valid_region(reference, max_fov=o.max_fov)
    recipe = PairRecipe(reference, camera, size, o.sampling(reference), target)
    recipe.sampler().check_reachable()
    return recipe, images


def decode_frames(images: list[RawImage], threads: int | None = None) -> np.ndarray:
    """All frames as one N×H×W×3 uint8 array (BGR): image files decoded in threads (OpenCV releases the GIL), frames
    of recordings (bags, videos; grey ones as BGR) in one pass per recording."""
    if not images:
        return np.zeros((0, 1, 1, 3), np.uint8)
    if any(i.frame is not None for i in images):  # frames of recordings: one pass per recording
        return np.stack(read_images(images, channels=3))
    with ThreadPoolExecutor(threads or len(os.sched_getaffinity(0))) as pool:
        return np.stack(list(pool.map(lambda i: read_image(i.path), images)))
