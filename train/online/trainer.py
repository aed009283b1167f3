"""An online run's data for one rank (frames in memory, the pair stream, the validation set) and the training
loop (train.loop.Trainer) it feeds."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from train import checkpoint
from train.data import build_val_loader
from train.errors import TrainError
from train.holdout import frame_sides
from train.loop import Trainer, resumed, total_steps
from train.model import check_size
from train.online.options import SAME_DATA, OnlineOptions, pick_render
from train.online.pairs import VAL_SEED, PairSpec, pair_loader
from train.online.recipe import decode_frames, open_recipe
from train.online.render import DeviceFrames, Feed, image_stats, rendered
from train.options import FitOptions


@dataclass(frozen=True)
class OnlinePlan:
    """What fit's Trainer reads of a data plan: the validation set's presence and the sizes (frames)."""

    train: str
    val: str | None
    n_train: int
    n_val: int | None

    def training(self) -> str:
        """What trains, in words (the Plan protocol)."""
        return self.train


class OnlineData:
    """Training frames in memory and the online validation set (or an offline build), for one rank."""

    def __init__(self, opts: FitOptions, device: torch.device, rank: int, world: int) -> None:
        o: OnlineOptions = opts.online
        self.opts, self.device, self.rank, self.world = opts, device, rank, world
        self.recipe, images = open_recipe(o, opts.target)
        check_size(*self.recipe.size)
        self.render = pick_render(o.render, o.interp, device)
        val_split = "none" if o.val_shards else opts.val_split
        train, val = frame_sides(images, opts.split, val_split, opts.val_fraction, opts.val_by)
        self.train_images, self.val_images = train, val
        self.frames = decode_frames(train)
        self.device_frames = DeviceFrames(self.frames, self.recipe, device) if self.render == "device" else None
        self.val_frames = decode_frames(val) if val else None
        desc_val = (f"offline build {o.val_shards}" if o.val_shards else
                    f"{len(val)} held-out frames × fixed-seed draws" if val else None)
        self.plan = OnlinePlan(f"{len(train)} frames × fresh draws ({self.render} render)", desc_val, len(train),
                               len(val) if val else None)
        self._val: list[dict] | None = None

    def spec(self, seed: int, start_batch: int = 0, count: int | None = None, frames: np.ndarray | None = None
             ) -> PairSpec:
        """A pair stream of this run's recipe and renderer."""
        return PairSpec(self.recipe, self.frames if frames is None else frames, seed, self.opts.batch, self.render,
                        start_batch, count, self.rank, self.world)

    def feed(self, step: int) -> Feed:
        """Training batches from step `step` on."""
        return Feed(iter(pair_loader(self.spec(self.opts.seed, step), self.opts.workers)), self.device_frames)

    def val_batches(self):
        """Validation batches: the fixed-seed pairs (rendered once) or the offline build's loader."""
        o = self.opts.online
        if o.val_shards:
            return build_val_loader(o.val_shards, self.opts.val_split, self.opts.target, self.recipe.size,
                                    self.opts.batch, self.opts.workers)
        if self._val is None:
            frames = self.val_frames
            spec = PairSpec(self.recipe, frames, VAL_SEED, self.opts.batch, self.render, count=self.opts.val_max)
            device_frames = DeviceFrames(frames, self.recipe, self.device) if self.render == "device" else None
            self._val = rendered(spec, self.opts.workers, device_frames)
        return self._val

    def rectify_rule(self) -> dict:
        """How raw images are rectified (predict --calib applies it): as a build records it, plus size and render."""
        o = self.opts.online
        return {"max_fov": o.max_fov, "interp": o.interp, "size": list(self.recipe.size), "crop": "valid_region",
                "render": self.render}

    def new_state(self) -> dict:
        """A fresh checkpoint: normalisation and label mean from the run's first images, untrained weights."""
        opts = self.opts
        checkpoint.check_normalize(opts.normalize)
        # The first stats_samples images of the run itself (seed and indices fixed): what the training sees.
        first = rendered(self.spec(opts.seed, count=opts.stats_samples), opts.workers, self.device_frames)
        label_mean = float(torch.cat([b["label"] for b in first]).double().mean())
        o = opts.online
        return checkpoint.fresh(opts, self.recipe.size, image_stats(first), "bgr", {
            "label_mean": label_mean, "appd_max": o.appd_max, "rectify": self.rectify_rule(),
            "data": {"online": True, "calib": o.calib, "camera": self.recipe.camera,
                     "sampling": self.recipe.sampling.describe(self.recipe.reference),
                     "train": self.plan.train, "val": self.plan.val, "n_train": self.plan.n_train,
                     "n_val": self.plan.n_val}})

    def check_resume(self, state: dict, last: Path) -> None:
        """Refuse a checkpoint whose data differs (another field of view, sampling, frames or seed; the kind of run,
        target and size: loop.resumed)."""
        started = state["config"].get("fit", {}).get("online") or {}
        changed = [k for k in SAME_DATA if started.get(k) != getattr(self.opts.online, k)]
        if state["config"]["fit"].get("seed") != self.opts.seed:
            changed.append("seed")
        if changed:
            names = ", ".join("--" + k.replace("_", "-") for k in changed)
            raise TrainError(f"{last}: started with another {names}; resume with the same, or choose another --run")


def online_trainer(opts: FitOptions, device: torch.device, rank: int, world: int, run: Path
                   ) -> tuple[OnlineTrainer, int]:
    """(the Trainer of an online run, its total steps): frames decoded, state fresh or resumed."""
    if opts.shards:
        raise TrainError("--online trains on --images; give --shards only without --online")
    data = OnlineData(opts, device, rank, world)
    steps = total_steps(opts, data.plan.n_train, world)
    if rank == 0:
        run.mkdir(parents=True, exist_ok=True)
    state = resumed(run, opts, data.recipe.size)
    if state is None:
        state = data.new_state()
    else:
        data.check_resume(state, run / "last.pt")
    return OnlineTrainer(opts, data, state, device, rank, world, run), steps


class OnlineTrainer(Trainer):
    """fit's training loop fed by online pairs; its summary adds how long the loop waited for data."""

    def __init__(self, opts: FitOptions, data: OnlineData, state: dict, device: torch.device, rank: int, world: int,
                 run: Path) -> None:
        super().__init__(opts, data.plan, state, device, rank, world, run)
        self.data = data
        self.feed: Feed | None = None

    def loader(self, step: int) -> Feed:
        """Infinite training batches from step `step` on: images step·B … of the run."""
        self.feed = self.data.feed(step)
        return self.feed

    def val_loader(self):
        """The validation batches (fixed-seed pairs rendered once, or the offline build)."""
        return self.data.val_batches()

    def describe(self) -> str:
        """'fit --online: train …, val …' of the pairs."""
        return f"fit --online: train {self.plan.train}, val {self.plan.val or 'none'}"

    def summary(self, step: int, loss: float | None, val: dict) -> dict:
        """fit's summary plus the data feed's report (wait fraction, draw and render ms per image)."""
        return {**super().summary(step, loss, val), **(self.feed.report() if self.feed else {}),
                "render": self.data.render}
