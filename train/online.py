"""`fit --online`: every training image a fresh pair (training frame, calibration) drawn as training goes.

Image i of a run is the pair that numpy's SeedSequence([seed, i]) chooses: its calibration is the build sampler's
draw(seed, i) (the same Θm, crop and label `appdgen build --seed SEED` gives sample i), its frame comes from
SeedSequence([seed, i, FRAME_STREAM]). Batch j holds images j·B … (j+1)·B − 1 (times the ranks), whichever
loader worker makes it, so a run is reproducible for any --workers and --resume continues exactly. Raw frames are
decoded once and kept in memory (on the training device for --render device). Renderers: `cpu` remaps in the
loader workers with OpenCV exactly as build does (geometry.remap.remap_image of the draw's rectification);
`device` draws in the workers and rectifies on the training device (train.warp.rectify_batch, grid_sample).
Validation uses fixed-seed pairs (VAL_SEED) of held-out frames, rendered once, so numbers compare between runs.
"""
from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from appdgen.calib.calibration import Calibration
from appdgen.cli.base import parse_size
from appdgen.sources.decode import read_image
from appdgen.sources.inputs import read_frames, resolve_inputs
from appdgen.sources.recordings import FrameChoice
from appdgen.sources.frames import RawImage
from appdgen.errors import AppdgenError
from appdgen.geometry.appd import px_to_pct
from appdgen.geometry.remap import DEFAULT_INTERP, remap_image
from appdgen.sampling.options import DEFAULT_ZERO_FRACTION, SamplingOptions
from appdgen.sampling.sampler import DEFAULT_APPD_MAX
from train import checkpoint
from train.data import PixelStats, Selection, StreamSpec, make_loader, open_shards
from train.errors import TrainError
from train.model import check_size

#: --render choices: auto = device on CUDA (when its interpolation exists there), else cpu.
RENDERS = ("auto", "cpu", "device")
#: The seed of the validation pairs: fixed, not the run's, so that every run validates on the same images.
VAL_SEED = 2**31 - 1
#: Third SeedSequence word of the frame choice (the sampler's own draw uses [seed, i]).
FRAME_STREAM = 1


@dataclass(frozen=True)
class OnlineOptions:
    """What `fit --online` takes besides FitOptions: raw frames, calibration and the build's sampling options."""

    calib: str
    images: str
    camera: str | None = None
    split_by: str = "none"
    size: str | None = None  # WxH, default the raw size
    ranges: str | None = None
    appd_max: float = DEFAULT_APPD_MAX
    zero_fraction: float = DEFAULT_ZERO_FRACTION
    max_fov: float | None = None
    interp: str = DEFAULT_INTERP
    render: str = "auto"
    val_shards: str | None = None  # validate on an offline build instead of fixed-seed online pairs
    topic: str | None = None  # which frames of a recording, as build's --topic/--every/--min-interval/--start/--end
    every: int = 1
    min_interval: float = 0.0
    start: float | None = None
    end: float | None = None

    def sampling(self, reference: Calibration) -> SamplingOptions:
        """The SamplingOptions these stand for (errors name the option)."""
        return SamplingOptions.parse(reference, self.ranges, self.appd_max, self.zero_fraction, self.max_fov,
                                     self.interp)


#: OnlineOptions that change the data: a resume must keep them (the renderer may change).
SAME_DATA = ("calib", "images", "camera", "split_by", "size", "ranges", "appd_max", "zero_fraction", "max_fov",
             "interp", "val_shards", "topic", "every", "min_interval", "start", "end")


def pick_render(render: str, interp: str, device: torch.device) -> str:
    """cpu or device: auto is device on CUDA unless grid_sample lacks the interpolation (lanczos4)."""
    from train.warp import DEVICE_INTERPOLATIONS

    if render not in RENDERS:
        raise TrainError(f"--render must be one of {', '.join(RENDERS)}, got {render!r}")
    if render == "auto":
        if device.type == "cuda" and interp not in DEVICE_INTERPOLATIONS:
            print(f"fit: --interp {interp} has no grid_sample kernel; rendering on the CPU (pass --interp cubic "
                  "for --render device)", file=sys.stderr)
        return "device" if device.type == "cuda" and interp in DEVICE_INTERPOLATIONS else "cpu"
    if render == "device" and interp not in DEVICE_INTERPOLATIONS:
        raise TrainError(f"--render device: --interp {interp} has no grid_sample kernel; use one of "
                         f"{', '.join(DEVICE_INTERPOLATIONS)}")
    return render


@dataclass(frozen=True)
class Scene:
    """The reference camera (and its id in the file), the output size (w, h) and the sampling options every pair
    is drawn with."""

    reference: Calibration
    camera: str
    size: tuple[int, int]
    sampling: SamplingOptions

    def sampler(self):
        """This process's labelling sampler (cached per options)."""
        return self.sampling.sampler(self.reference, self.size)

    def render(self, raw: np.ndarray, draw) -> np.ndarray:
        """The cpu renderer: a raw frame through a draw's rectification, H×W×3 uint8, as build renders sample i."""
        return remap_image(raw, draw.rect, self.sampling.interp)


def open_scene(o: OnlineOptions) -> tuple[Scene, list[RawImage]]:
    """The calibration, size, sampling options (checked: reachable --appd-max) and the listed raw images."""
    try:
        choice = FrameChoice(o.every, o.min_interval, o.start, o.end)
        inputs = resolve_inputs(o.images, o.calib, o.camera, o.split_by, o.topic, choice, check_grey=False)
        reference, camera, images = inputs.reference, inputs.camera, list(inputs.images)
        from appdgen.geometry.crop import check_output_size, valid_region

        size = check_output_size(reference, parse_size(o.size) or reference.size)
        valid_region(reference, max_fov=o.max_fov)
        scene = Scene(reference, camera, size, o.sampling(reference))
        scene.sampler().check_reachable()
    except AppdgenError as exc:
        raise TrainError(str(exc)) from None
    return scene, images


def frame_sides(images: list[RawImage], split: str, val_split: str, val_fraction: float, val_by: str
                ) -> tuple[list[RawImage], list[RawImage]]:
    """(training frames, validation frames) under fit's holdout rules: a named split, else whole recordings
    (KITTI drive, else folder) or single images held out by hash (train.data's recording/held_out)."""
    from train.fit import holdout_unit

    unsplit = all(i.split == "all" for i in images)  # --split-by none: every frame is the training split's
    train = [i for i in images if unsplit or i.split == split]
    if not train:
        raise TrainError(f"--images: no frames of split {split!r} (found {', '.join(sorted({i.split for i in images}))})")
    if val_split == "auto":
        val_split = "val" if any(i.split == "val" for i in images) and not unsplit else "holdout"
    if val_split == "none":
        return train, []
    if val_split != "holdout":
        val = [i for i in images if i.split == val_split]
        if not val:
            raise TrainError(f"--val-split {val_split!r}: no frames of that split")
        return train, val
    if not 0 < val_fraction < 1:
        raise TrainError(f"--val-fraction must be in (0, 1), got {val_fraction}")
    labels = {"split": [split] * len(train), "raw_path": [i.name for i in train]}
    by, held = holdout_unit(labels, _Holdout(split, val_by, val_fraction))
    side = {s: Selection(split, val_fraction, s, None, by, held) for s in ("train", "val")}
    meta = [{"split": split, "raw_path": i.name, "key": i.name} for i in train]
    return ([i for i, m in zip(train, meta) if side["train"].accepts(m)],
            [i for i, m in zip(train, meta) if side["val"].accepts(m)])


@dataclass(frozen=True)
class _Holdout:
    """The FitOptions fields holdout_unit reads."""

    split: str
    val_by: str
    val_fraction: float


def decode_frames(images: list[RawImage], threads: int | None = None) -> np.ndarray:
    """All frames as one N×H×W×3 uint8 array (BGR): image files decoded in threads (OpenCV releases the GIL), frames
    of recordings (bags, videos; grey ones as BGR) in one pass per recording."""
    if not images:
        return np.zeros((0, 1, 1, 3), np.uint8)
    if any(i.frame is not None for i in images):  # frames of recordings: one pass per recording
        try:
            return np.stack(read_frames(images, channels=3))
        except AppdgenError as exc:
            raise TrainError(str(exc)) from None
    with ThreadPoolExecutor(threads or len(os.sched_getaffinity(0))) as pool:
        try:
            decoded = list(pool.map(lambda i: read_image(i.path), images))
        except AppdgenError as exc:
            raise TrainError(str(exc)) from None
    return np.stack(decoded)


def frame_of(seed: int, index: int, frames: int) -> int:
    """The frame of image `index` of a run with this seed (SeedSequence([seed, index, FRAME_STREAM]))."""
    return int(np.random.default_rng([seed, index, FRAME_STREAM]).integers(frames))


@dataclass(frozen=True)
class PairSpec:
    """A stream of batches of pairs: images `start`·B … onwards (count images, None = forever) for one rank."""

    scene: Scene
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
        sampler = s.scene.sampler()
        labels, frames, params, new_ks, images = [], [], [], [], []
        draw_s = render_s = 0.0
        for i in range(first, last):
            t0 = time.perf_counter()
            draw = sampler.draw(s.seed, i)
            frame = frame_of(s.seed, i, len(s.frames))
            t1 = time.perf_counter()
            if s.render == "cpu":
                images.append(s.scene.render(s.frames[frame], draw).transpose(2, 0, 1))
            render_s += time.perf_counter() - t1
            draw_s += t1 - t0
            labels.append(px_to_pct(draw.appd_px, s.scene.reference))
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


class DeviceFrames:
    """Raw frames on the training device and the renderer that rectifies a batch of draws from them."""

    def __init__(self, frames: np.ndarray, scene: Scene, device: torch.device) -> None:
        # N×3×H×W uint8 on the device: 2,000 KITTI frames are 4.3 GB.
        self.raw = torch.from_numpy(frames).to(device).permute(0, 3, 1, 2)
        self.scene, self.device = scene, device

    def render(self, batch: dict) -> torch.Tensor:
        """uint8 B×3×h×w images of a batch's draws (train.warp.rectify_batch)."""
        from train.warp import rectify_batch

        names = self.scene.reference.param_names
        calibs = [self.scene.reference.replace(**dict(zip(names, p))) for p in batch["params"].tolist()]
        raw = self.raw[batch["frame"].to(self.device)]
        return rectify_batch(raw, calibs, list(batch["new_k"].numpy()), self.scene.size, self.scene.sampling.interp)


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


@dataclass(frozen=True)
class OnlinePlan:
    """What fit's Trainer reads of a data plan: the validation set's presence and the sizes (frames)."""

    train: str
    val: str | None
    n_train: int
    n_val: int | None


class OnlineData:
    """Training frames in memory and the online validation set (or an offline build), for one rank."""

    def __init__(self, opts, device: torch.device, rank: int, world: int) -> None:
        o: OnlineOptions = opts.online
        self.opts, self.device, self.rank, self.world = opts, device, rank, world
        self.scene, images = open_scene(o)
        check_size(*self.scene.size)
        self.render = pick_render(o.render, o.interp, device)
        val_split = "none" if o.val_shards else opts.val_split
        train, val = frame_sides(images, opts.split, val_split, opts.val_fraction, opts.val_by)
        self.train_images, self.val_images = train, val
        self.frames = decode_frames(train)
        self.device_frames = DeviceFrames(self.frames, self.scene, device) if self.render == "device" else None
        self.val_frames = decode_frames(val) if val else None
        desc_val = (f"offline build {o.val_shards}" if o.val_shards else
                    f"{len(val)} held-out frames × fixed-seed draws" if val else None)
        self.plan = OnlinePlan(f"{len(train)} frames × fresh draws ({self.render} render)", desc_val, len(train),
                               len(val) if val else None)
        self._val: list[dict] | None = None

    def spec(self, seed: int, start_batch: int = 0, count: int | None = None, frames: np.ndarray | None = None
             ) -> PairSpec:
        """A pair stream of this run's scene and renderer."""
        return PairSpec(self.scene, self.frames if frames is None else frames, seed, self.opts.batch, self.render,
                        start_batch, count, self.rank, self.world)

    def feed(self, step: int) -> Feed:
        """Training batches from step `step` on."""
        return Feed(iter(pair_loader(self.spec(self.opts.seed, step), self.opts.workers)), self.device_frames)

    def val_batches(self):
        """Validation batches: the fixed-seed pairs (rendered once) or the offline build's loader."""
        o = self.opts.online
        if o.val_shards:
            ss = open_shards(o.val_shards)
            split = self.opts.val_split if self.opts.val_split not in ("auto", "holdout", "none") else \
                ("val" if ss.split_count("val") else next(iter(ss.build.get("counts", {}).get("splits", {})), "val"))
            spec = StreamSpec(ss.for_split(split), Selection(split), self.scene.size)
            return make_loader(spec, self.opts.batch, self.opts.workers)
        if self._val is None:
            frames = self.val_frames
            spec = PairSpec(self.scene, frames, VAL_SEED, self.opts.batch, self.render, count=self.opts.val_max)
            device_frames = DeviceFrames(frames, self.scene, self.device) if self.render == "device" else None
            self._val = rendered(spec, self.opts.workers, device_frames)
        return self._val

    def has_val(self) -> bool:
        """Whether there is a validation set."""
        return self.plan.val is not None

    def rule(self) -> dict:
        """How raw images are rectified (predict --calib applies it): as a build records it, plus size and render."""
        o = self.opts.online
        return {"max_fov": o.max_fov, "interp": o.interp, "size": list(self.scene.size), "crop": "valid_region",
                "render": self.render}

    def new_state(self) -> dict:
        """A fresh checkpoint: normalisation and label mean from the run's first images, untrained weights."""
        opts = self.opts
        checkpoint.check_normalize(opts.normalize)
        # The first stats_samples images of the run itself (seed and indices fixed): what the training sees.
        first = rendered(self.spec(opts.seed, count=opts.stats_samples), opts.workers, self.device_frames)
        label_mean = float(torch.cat([b["label"] for b in first]).double().mean())
        o = opts.online
        return checkpoint.fresh(opts, self.scene.size, image_stats(first), "bgr", {
            "label_mean": label_mean, "appd_max": o.appd_max, "rectify": self.rule(),
            "data": {"online": True, "calib": o.calib, "camera": self.scene.camera,
                     "sampling": self.scene.sampling.describe(self.scene.reference),
                     "train": self.plan.train, "val": self.plan.val, "n_train": self.plan.n_train,
                     "n_val": self.plan.n_val}})

    def check_resume(self, state: dict, last: Path) -> None:
        """Refuse a checkpoint whose data differs (another size, field of view, sampling or frames)."""
        started = state["config"].get("fit", {}).get("online") or {}
        changed = [k for k in SAME_DATA if started.get(k) != getattr(self.opts.online, k)]
        if not state["config"].get("data", {}).get("online"):
            raise TrainError(f"{last}: an offline (--shards) run; resume it with --shards, or choose another --run")
        if state["config"]["fit"].get("seed") != self.opts.seed:
            changed.append("seed")
        if changed:
            names = ", ".join("--" + k.replace("_", "-") for k in changed)
            raise TrainError(f"{last}: started with another {names}; resume with the same, or choose another --run")
        cfg = checkpoint.model_config(state)
        if (cfg.width, cfg.height) != self.scene.size:
            raise TrainError(f"{last} was trained on {cfg.width}x{cfg.height} images, not {self.scene.size[0]}x"
                             f"{self.scene.size[1]}")



def online_trainer(opts, device: torch.device, rank: int, world: int, run: Path):
    """(the Trainer of an online run, its total steps): frames decoded, state fresh or resumed."""
    from train.fit import resumed, total_steps

    if opts.shards:
        raise TrainError("--online trains on --images; give --shards only without --online")
    data = OnlineData(opts, device, rank, world)
    steps = total_steps(opts, data.plan.n_train, world)
    if rank == 0:
        run.mkdir(parents=True, exist_ok=True)
    state = resumed(run, opts)
    if state is None:
        state = data.new_state()
    else:
        data.check_resume(state, run / "last.pt")
    return OnlineTrainer(opts, data, state, device, rank, world, run), steps


def _trainer_base():
    """train.fit.Trainer (imported late: fit imports this module only for --online)."""
    from train.fit import Trainer

    return Trainer


class OnlineTrainer(_trainer_base()):
    """fit's training loop fed by online pairs; its summary adds how long the loop waited for data."""

    def __init__(self, opts, data: OnlineData, state: dict, device: torch.device, rank: int, world: int,
                 run: Path) -> None:
        super().__init__(opts, None, data.plan, state, device, rank, world, run)
        self.data = data
        self.feed: Feed | None = None

    def loader(self, step: int) -> Feed:
        """Infinite training batches from step `step` on: images step·B … of the run."""
        self.feed = self.data.feed(step)
        return self.feed

    def val_loader(self):
        """The validation batches (fixed-seed pairs rendered once, or the offline build)."""
        return self.data.val_batches()

    def announce(self, step: int, steps: int) -> None:
        """One stderr line saying what this run does."""
        if self.rank != 0 or self.opts.quiet:
            return
        p, cfg = self.plan, self.model.cfg
        print(f"fit --online: {cfg.width}x{cfg.height} px, train {p.train}, val {p.val or 'none'}, steps {step}→"
              f"{steps}, batch {self.opts.batch}×{self.world}, {self.device}, autocast {self.dtype or 'off'}, "
              f"{torch.get_num_threads()} threads, {self.opts.workers} loader workers", file=sys.stderr)

    def summary(self, step: int, loss: float | None, val: dict) -> dict:
        """fit's summary plus the data feed's report (wait fraction, draw and render ms per image)."""
        return {**super().summary(step, loss, val), **(self.feed.report() if self.feed else {}),
                "render": self.data.render}
