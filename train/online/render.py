"""Pairs rendered on the training device (--render device), the feed that times how long training waits for
data, and the pixel statistics of rendered batches."""
from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import torch

from train.data import PixelStats
from train.online.pairs import PairSpec, pair_loader
from train.online.recipe import PairRecipe
from train.warp import rectify_batch


class DeviceFrames:
    """Raw frames on the training device and the renderer that rectifies a batch of draws from them."""

    def __init__(self, frames: np.ndarray, recipe: PairRecipe, device: torch.device) -> None:
        # N×3×H×W uint8 on the device: 2,000 KITTI frames are 4.3 GB.
        self.raw = torch.from_numpy(frames).to(device).permute(0, 3, 1, 2)
        self.recipe, self.device = recipe, device

    def render(self, batch: dict) -> torch.Tensor:
        """uint8 B×3×h×w images of a batch's draws (train.warp.rectify_batch)."""
        names = self.recipe.reference.param_names
        calibs = [self.recipe.reference.replace(**dict(zip(names, p, strict=True))) for p in batch["params"].tolist()]
        raw = self.raw[batch["frame"].to(self.device)]
        return rectify_batch(raw, calibs, list(batch["new_k"].numpy()), self.recipe.size, self.recipe.sampling.interp)


class Feed:
    """Training batches with images, timing how long the trainer waits for them and what they cost to make."""

    def __init__(self, batches: Iterator[dict], device_frames: DeviceFrames | None) -> None:
        self.batches, self.device_frames = batches, device_frames
        self.wait_s = self.draw_s = self.render_s = 0.0
        self.images = 0
        self.started = time.perf_counter()

    def __iter__(self) -> "Feed":
        return self

    def __next__(self) -> dict:
        t0 = time.perf_counter()
        batch = next(self.batches)
        if self.device_frames is not None:
            t1 = time.perf_counter()
            batch["image"] = self.device_frames.render(batch)
            batch["render_s"] += time.perf_counter() - t1
        self.wait_s += time.perf_counter() - t0
        self.draw_s += batch["draw_s"]
        self.render_s += batch["render_s"]
        self.images += len(batch["label"])
        return batch

    def report(self) -> dict:
        """Fraction of the loop's time spent waiting for data, and ms per image drawing and rendering."""
        total = time.perf_counter() - self.started
        n = max(self.images, 1)
        return {"data_wait_fraction": self.wait_s / total if total > 0 else None,
                "draw_ms_per_image": 1e3 * self.draw_s / n, "render_ms_per_image": 1e3 * self.render_s / n}


def rendered(spec: PairSpec, workers: int, device_frames: DeviceFrames | None) -> list[dict]:
    """Every batch of a finite spec, with images (uint8, on the CPU for cpu, on the device for device)."""
    return list(Feed(iter(pair_loader(spec, workers)), device_frames))


def image_stats(batches: list[dict]) -> tuple[list[float], list[float], np.ndarray]:
    """Per-channel mean and std of pixels in [0, 1] and the per-pixel mean image (C×H×W float32) of batches."""
    stats = PixelStats()
    for batch in batches:
        stats.add(batch["image"].cpu().numpy())
    return stats.result()
