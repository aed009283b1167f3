"""Which pair image i of a run is (its frame and the sampler's draw, both from the seed), and the loader that makes
batches of them in any number of workers, reproducibly."""
from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from train.online.recipe import PairRecipe

#: The seed of the validation pairs: fixed, not the run's, so that every run validates on the same images.
VAL_SEED = 2**31 - 1
#: Third SeedSequence word of the frame choice (the sampler's own draw uses [seed, i]).
FRAME_STREAM = 1


def frame_of(seed: int, index: int, frames: int) -> int:
    """The frame of image `index` of a run with this seed (SeedSequence([seed, index, FRAME_STREAM]))."""
    return int(np.random.default_rng([seed, index, FRAME_STREAM]).integers(frames))


@dataclass(frozen=True)
class PairSpec:
    """A stream of batches of pairs: images `start`·B … onwards (count images, None = forever) for one rank."""

    recipe: PairRecipe
    frames: np.ndarray  # N×H×W×3 uint8: shared with forked loader workers, never copied
    seed: int
    batch: int
    render: str  # cpu: images in the batch; device: the draws only (the trainer renders)
    start_batch: int = 0
    count: int | None = None
    rank: int = 0
    world: int = 1

    def batches(self) -> int | None:
        """Number of batches (None: forever)."""
        return None if self.count is None else -(-self.count // self.batch)


class PairStream(IterableDataset):
    """Yields whole batches: {"label": float32 B, "frame": int64 B, "params", "new_k": float64, "image" (cpu) uint8
    B×3×h×w, "draw_s", "render_s": seconds spent}. Loader worker w of W makes batches start + w, start + w + W, …,
    which the DataLoader delivers in order."""

    def __init__(self, spec: PairSpec) -> None:
        super().__init__()
        self.spec = spec

    def __iter__(self) -> Iterator[dict]:
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info else (0, 1)
        total = self.spec.batches()
        j = self.spec.start_batch + worker
        while total is None or j < total:
            yield self.make(j)
            j += workers

    def make(self, j: int) -> dict:
        """Batch j of this rank."""
        s = self.spec
        first = (j * s.world + s.rank) * s.batch
        last = first + s.batch if s.count is None else min(first + s.batch, s.count)
        sampler = s.recipe.sampler()
        labels, frames, params, new_ks, images = [], [], [], [], []
        draw_s = render_s = 0.0
        for i in range(first, last):
            t0 = time.perf_counter()
            draw = sampler.draw(s.seed, i)
            frame = frame_of(s.seed, i, len(s.frames))
            t1 = time.perf_counter()
            if s.render == "cpu":
                images.append(s.recipe.render(s.frames[frame], draw).transpose(2, 0, 1))
            render_s += time.perf_counter() - t1
            draw_s += t1 - t0
            labels.append(s.recipe.label(draw))
            frames.append(frame)
            params.append(list(draw.calib.params().values()))
            new_ks.append(draw.rect.new_camera_matrix)
        out = {"label": torch.tensor(labels, dtype=torch.float32), "frame": torch.tensor(frames),
               "params": torch.tensor(params, dtype=torch.float64),
               "new_k": torch.from_numpy(np.stack(new_ks)), "draw_s": draw_s, "render_s": render_s}
        if images:
            out["image"] = torch.from_numpy(np.stack(images))
        return out


def pair_loader(spec: PairSpec, workers: int) -> DataLoader:
    """Batches of a PairStream, `workers` processes drawing (and for cpu, rendering)."""
    # Its own generator: a DataLoader draws its workers' base seed from the global RNG otherwise, and a resumed
    # run, which opens its loader after restoring that RNG, would then drop other units than the uninterrupted one.
    return DataLoader(PairStream(spec), batch_size=None, num_workers=workers, persistent_workers=False,
                      pin_memory=torch.cuda.is_available() and spec.render == "cpu",
                      prefetch_factor=4 if workers > 0 else None, generator=torch.Generator().manual_seed(0))
