"""`fit`: stream shards, train the paper's CNN on APPD (% of diagonal) with MSE, checkpoint, validate."""
from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F

from appdgen.dataset.layout import BUILD_JSON, INDEX, LABEL_COLUMN
from appdgen.util.progress import Progress
from train import checkpoint, runtime
from train.data import (
    HOLDOUT_UNITS, Selection, ShardSet, ShardStream, StreamSpec, channel_stats, count_selected, held_out,
    make_loader, open_shards, read_labels, recording,
)
from train.errors import TrainError
from train.model import AppdNet, check_size

if TYPE_CHECKING:
    from train.online import OnlineOptions

#: Options that fix the order samples arrive in; a resume with the same ones continues the data exactly.
RESUME_SAME = ("batch", "workers", "seed", "shuffle_buffer")
LOG_COLUMNS = ("step", "train_loss", "val_loss", "val_mae", "lr", "images_per_s")


@dataclass(frozen=True)
class FitOptions:
    """Everything `python -m train fit` takes; stored in the checkpoint as plain values."""

    shards: str | None  # an offline build; None with `online`
    run: str
    split: str = "train"
    val_split: str = "auto"  # a split name, "auto" (val if present, else holdout) or "none"
    val_fraction: float = 0.1  # recordings (or raw images) held out by hash when there is no val split
    val_by: str = "recording"  # what the holdout keeps whole: "recording" (KITTI drive, else folder) or "image"
    steps: int | None = None
    epochs: float | None = None
    batch: int = 32
    lr: float = 1e-4
    workers: int = 1
    ckpt_every: int = 200
    val_every: int | None = None  # default: every checkpoint
    val_max: int = 1000
    log_every: int = 10
    max_minutes: float | None = None  # stop early (checkpointed, validated) after this wall time
    shuffle_buffer: int = 1000
    resume: bool = False
    seed: int = 0
    device: str = "auto"
    precision: str = "auto"
    stats_samples: int = 256
    normalize: str = "channel"  # "channel": per-channel mean/std; "pixel": a per-pixel mean image, channel std
    quiet: bool = False
    online: "OnlineOptions | None" = None  # train on fresh pairs drawn as it goes (train.online), not shards


@dataclass(frozen=True)
class DataPlan:
    """Train and validation selections and their sizes (None when unknown)."""

    train: Selection
    val: Selection | None
    n_train: int | None
    n_val: int | None


def only_split(ss: ShardSet, opts: FitOptions) -> FitOptions:
    """opts, on the build's only split when it has none named --split (a build without --split-by has one: 'all')."""
    names = ss.split_names()
    if ss.split_count(opts.split) or len(names) != 1:
        return opts
    print(f"fit: {ss.root} has no split {opts.split!r}; training on its only split {names[0]!r} "
          f"({ss.split_count(names[0])} samples)", file=sys.stderr)
    return dataclasses.replace(opts, split=names[0])


def plan_data(ss: ShardSet, labels: dict | None, opts: FitOptions) -> DataPlan:
    """Pick the validation set: a named split, else a hash holdout of the training split's recordings."""
    if ss.split_count(opts.split) == 0:
        raise TrainError(f"{ss.root}: no samples of split {opts.split!r} ({BUILD_JSON} lists none)")
    val_split = opts.val_split
    if val_split == "auto":
        val_split = "val" if ss.split_count("val") > 0 else "holdout"
    if val_split == "none":
        return DataPlan(Selection(opts.split), None, _known_count(ss, labels, Selection(opts.split)), None)
    if val_split != "holdout":
        if ss.split_count(val_split) == 0:
            raise TrainError(f"{ss.root}: --val-split {val_split!r} has no samples")
        train, val = Selection(opts.split), Selection(val_split)
    else:
        if not 0 < opts.val_fraction < 1:
            raise TrainError(f"--val-fraction must be in (0, 1), got {opts.val_fraction}")
        raw = dict(zip(labels["key"], labels["raw_path"])) if labels else None
        if raw is None:
            print(f"fit: no {INDEX}; holding out by each sample's json raw_path, else its key", file=sys.stderr)
        by, held = holdout_unit(labels, opts)
        train = Selection(opts.split, opts.val_fraction, "train", raw, by, held)
        val = Selection(opts.split, opts.val_fraction, "val", raw, by, held)
    return DataPlan(train, val, _known_count(ss, labels, train), _known_count(ss, labels, val))


def holdout_unit(labels: dict | None, opts: FitOptions) -> tuple[str, frozenset[str] | None]:
    """--val-by and, by recording, the held-out recordings (None: a hash coin per recording, without labels).

    A split recorded in one folder (e.g. synthetic frames, each its own scene) is held out by image: a holdout
    by recording would have to put all of it on one side.
    """
    if opts.val_by not in HOLDOUT_UNITS:
        raise TrainError(f"--val-by must be one of {', '.join(HOLDOUT_UNITS)}, got {opts.val_by!r}")
    if opts.val_by == "image" or labels is None:
        return opts.val_by, None
    sources = labels.get("source") or [None] * len(labels["split"])
    found = {recording(str(r), o) for s, r, o in zip(labels["split"], labels["raw_path"], sources) if s == opts.split}
    if len(found) < 2:
        print(f"fit: split {opts.split!r} is one recording ({next(iter(found), '?')!r}); holding out by image",
              file=sys.stderr)
        return "image", None
    return "recording", held_out(found, opts.val_fraction)


def _known_count(ss: ShardSet, labels: dict | None, sel: Selection) -> int | None:
    """Size of a selection from labels.parquet, or from build.json when no holdout applies."""
    n = count_selected(labels, sel)
    if n is None and sel.holdout <= 0 and ss.build:
        n = ss.split_count(sel.split)
    return n


def total_steps(opts: FitOptions, n_train: int | None, world: int) -> int:
    """Optimizer steps to run: --steps, or --epochs × samples / (batch × ranks)."""
    if (opts.steps is None) == (opts.epochs is None):
        raise TrainError("give exactly one of --steps or --epochs")
    if opts.steps is not None:
        return opts.steps
    if not n_train:
        raise TrainError(f"--epochs needs the sample count ({INDEX} or {BUILD_JSON}); use --steps")
    return max(1, math.ceil(opts.epochs * n_train / (opts.batch * world)))


def image_size(ss: ShardSet, sel: Selection) -> tuple[int, int]:
    """Image size (w, h) from build.json, else from the first sample."""
    if ss.size is not None:
        return (int(ss.size[0]), int(ss.size[1]))
    first = next(iter(ShardStream(StreamSpec(ss.for_split(sel.split), sel, limit=1))), None)
    if first is None:
        raise TrainError(f"{ss.root}: no samples for {sel.describe()}")
    _, h, w = first["image"].shape
    return (w, h)


def new_state(ss: ShardSet, labels: dict | None, plan: DataPlan, opts: FitOptions) -> dict:
    """A fresh checkpoint dict: normalisation from a spread subset, label mean, untrained weights."""
    size = image_size(ss, plan.train)
    check_size(*size)
    checkpoint.check_normalize(opts.normalize)
    spec = StreamSpec(ss.for_split(plan.train.split), plan.train, size)
    mean, std, sub_labels, mean_image = channel_stats(spec, opts.stats_samples, plan.n_train)
    label_mean = _train_label_mean(labels, plan.train) if labels else sum(sub_labels) / len(sub_labels)
    channels = "grey" if len(mean) == 1 else "bgr"  # the build's samples: 1 channel from a mono source
    return checkpoint.fresh(opts, size, (mean, std, mean_image), channels, {
        "label_mean": label_mean, "appd_max": ss.appd_max,
        "rectify": ss.rectify_rule(),  # predict --calib rectifies raw images by the same rule
        "data": {"shards": str(ss.root), "train": plan.train.describe(),
                 "val": plan.val.describe() if plan.val else None, "n_train": plan.n_train, "n_val": plan.n_val}})


def _train_label_mean(labels: dict, sel: Selection) -> float:
    """Mean appd_pct over a selection's rows of labels.parquet (exact, no image decoding)."""
    vals = [a for k, s, r, a in zip(labels["key"], labels["split"], labels["raw_path"], labels[LABEL_COLUMN])
            if sel.accepts({"key": k, "split": s, "raw_path": r})]
    return sum(vals) / len(vals)


def resumed(run: Path, opts: FitOptions) -> dict | None:
    """run/last.pt with --resume, None to start fresh; refuses to overwrite a run without --resume."""
    last = run / "last.pt"
    if last.exists() and not opts.resume:
        raise TrainError(f"{last} exists: pass --resume to continue it, or choose another --run")
    if not last.exists():
        if opts.resume:
            print(f"fit: --resume but no {last}; starting fresh", file=sys.stderr)
        return None
    return checkpoint.load(last)


def load_or_init(ss: ShardSet, labels: dict | None, plan: DataPlan, opts: FitOptions, run: Path) -> dict:
    """The checkpoint to start from: run/last.pt with --resume, else a fresh one (never overwrites)."""
    state = resumed(run, opts)
    if state is None:
        return new_state(ss, labels, plan, opts)
    last = run / "last.pt"
    if state["config"].get("data", {}).get("online"):
        raise TrainError(f"{last}: an --online run; resume it with --online, or choose another --run")
    started = state["config"].get("fit", {})
    changed = [k for k in RESUME_SAME if k in started and started[k] != getattr(opts, k)]
    if changed:
        print(f"fit: resuming with another {', '.join('--' + k.replace('_', '-') for k in changed)} than the run "
              f"started with: the data continues from an approximate position", file=sys.stderr)
    cfg = checkpoint.model_config(state)
    size = image_size(ss, plan.train)
    if (cfg.width, cfg.height) != size:
        raise TrainError(f"{last} was trained on {cfg.width}x{cfg.height} images, "
                         f"but the shards are {size[0]}x{size[1]}")
    mismatch = checkpoint.rule_mismatch(state, ss.rectify_rule())
    if mismatch:
        raise TrainError(f"{last}: {mismatch}; resume on shards built with the same --max-fov, or start a new --run")
    return state


class CsvLog:
    """run/log.csv, appended across resumes, one row per log interval."""

    def __init__(self, path: Path, enabled: bool) -> None:
        self.path, self.enabled = path, enabled
        if enabled and not path.exists():
            with open(path, "w", newline="") as fh:
                csv.writer(fh).writerow(LOG_COLUMNS)

    def row(self, **values: float | int | None) -> None:
        """Append one row; missing columns stay empty."""
        if not self.enabled:
            return
        with open(self.path, "a", newline="") as fh:
            csv.writer(fh).writerow(["" if values.get(c) is None else _fmt(values[c]) for c in LOG_COLUMNS])


def _fmt(v: float | int) -> str:
    """Compact CSV number."""
    return str(v) if isinstance(v, int) else f"{v:.6g}"


def to_input(batch: dict, device: torch.device) -> torch.Tensor:
    """uint8 N×3×H×W → float [0, 1] on device, channels_last (≈2× faster convs on CPU and GPU)."""
    x = batch["image"].to(device, non_blocking=True).float().div_(255.0)
    return x.contiguous(memory_format=torch.channels_last)


def train_step(net: torch.nn.Module, opt: torch.optim.Optimizer, batch: dict, device: torch.device,
               dtype: torch.dtype | None) -> torch.Tensor:
    """One Adam step on MSE(pred, appd_pct); returns the detached loss (no host sync)."""
    x = to_input(batch, device)
    y = batch["label"].to(device, non_blocking=True)
    with runtime.autocast(device, dtype):
        pred = net(x)
    loss = F.mse_loss(pred.float(), y)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return loss.detach()


@torch.no_grad()
def validate(model: AppdNet, loader, device: torch.device, dtype, limit: int) -> dict:
    """MSE loss and MAE (APPD %) over up to `limit` samples."""
    model.eval()
    sq = ab = 0.0
    n = 0
    for batch in loader:
        with runtime.autocast(device, dtype):
            pred = model(to_input(batch, device)).float()
        err = pred - batch["label"].to(device)
        sq += float((err**2).sum())
        ab += float(err.abs().sum())
        n += len(err)
        if n >= limit:
            break
    model.train()
    return {"val_loss": sq / max(n, 1), "val_mae": ab / max(n, 1), "val_n": n}


def fit(opts: FitOptions) -> dict | None:
    """Train to the requested step count; rank 0 returns a summary (step, losses, checkpoint paths)."""
    device = runtime.pick_device(opts.device)
    runtime.setup_threads(device)
    runtime.init_distributed(device)
    rank, world = runtime.rank(), runtime.world_size()
    run = Path(opts.run)
    if opts.online is not None:
        from train.online import online_trainer

        trainer, steps = online_trainer(opts, device, rank, world, run)
    else:
        trainer, steps = shard_trainer(opts, device, rank, world, run)
    try:
        summary = trainer.train(steps)
    finally:
        runtime.finish_distributed()
    return summary if rank == 0 else None


def shard_trainer(opts: FitOptions, device: torch.device, rank: int, world: int, run: Path) -> tuple["Trainer", int]:
    """(the Trainer of a run on an offline build, its total steps)."""
    if not opts.shards:
        raise TrainError("give --shards (a build folder), or --online with --calib and --images")
    ss = open_shards(opts.shards)
    opts = only_split(ss, opts)
    labels = read_labels(ss.root)
    plan = plan_data(ss, labels, opts)
    steps = total_steps(opts, plan.n_train, world)
    if rank == 0:
        run.mkdir(parents=True, exist_ok=True)
    state = load_or_init(ss, labels, plan, opts, run)
    return Trainer(opts, ss, plan, state, device, rank, world, run), steps


class Trainer:
    """The training loop and its bookkeeping for one process (rank) of a run."""

    def __init__(self, opts: FitOptions, ss: ShardSet, plan: DataPlan, state: dict, device: torch.device,
                 rank: int, world: int, run: Path) -> None:
        self.opts, self.ss, self.plan, self.state = opts, ss, plan, state
        self.device, self.rank, self.world, self.run = device, rank, world, run
        self.dtype = runtime.autocast_dtype(device, opts.precision)
        self.model = checkpoint.build_model(state).to(device).to(memory_format=torch.channels_last).train()
        self.opt = torch.optim.Adam(self.model.parameters(), lr=opts.lr)
        if state["optimizer"] is not None:
            self.opt.load_state_dict(state["optimizer"])
            for group in self.opt.param_groups:
                group["lr"] = opts.lr  # a resumed run takes the lr given now
        if state.get("rng") is not None:
            torch.set_rng_state(state["rng"])  # dropout continues as it would have: a resume repeats the losses
        self.net = self.model
        if world > 1:
            from torch.nn.parallel import DistributedDataParallel

            self.net = DistributedDataParallel(self.model, device_ids=[device.index] if device.type == "cuda" else None)
        self.log = CsvLog(run / "log.csv", rank == 0)
        self.trained = Tally()  # images and seconds of training steps in this process, validation excluded
        self.size = (self.model.cfg.width, self.model.cfg.height)

    def loader(self, step: int):
        """Infinite shuffled training batches for this rank, from where step `step` left the data."""
        spec = StreamSpec(self.ss.for_split(self.plan.train.split), self.plan.train, self.size, loop=True,
                          shuffle=True, seed=self.opts.seed, buffer=self.opts.shuffle_buffer, rank=self.rank,
                          world=self.world, skip_batches=step, batch=self.opts.batch)
        return iter(make_loader(spec, self.opts.batch, self.opts.workers))

    def val_loader(self):
        """Validation batches in shard order (rank 0 validates alone)."""
        sel = self.plan.val
        spec = StreamSpec(self.ss.for_split(sel.split), sel, self.size)
        return make_loader(spec, self.opts.batch, self.opts.workers)

    def train(self, steps: int) -> dict:
        """Run until `steps` optimizer steps; log, validate, checkpoint on the way and at the end."""
        step = int(self.state["step"])
        if step >= steps:
            print(f"fit: checkpoint is already at step {step} ≥ {steps}; nothing to do", file=sys.stderr)
            return self.summary(step, None, {})
        self.announce(step, steps)
        progress = Progress(steps, "steps", enabled=self.rank == 0 and not self.opts.quiet, every=30.0, done=step)
        batches, window = self.loader(step), Window(self.device)
        last, deadline = {"train_loss": None}, Deadline(self.opts.max_minutes)
        while step < steps:
            batch = next(batches, None)
            if batch is None:
                raise TrainError(f"no training samples for {self.plan.train.describe()} on rank {self.rank}")
            window.add(train_step(self.net, self.opt, batch, self.device, self.dtype), len(batch["label"]) * self.world)
            step += 1
            if step % self.opts.log_every == 0 and deadline.passed():
                steps = step  # out of time: make this the final step
                if self.rank == 0:
                    print(f"\nfit: --max-minutes {self.opts.max_minutes:g} reached; stopping at step {step}",
                          file=sys.stderr)
            last = self.bookkeeping(step, steps, window, progress) or last
        progress.close()
        return self.summary(step, last["train_loss"], {k: v for k, v in last.items() if k.startswith("val")})

    def bookkeeping(self, step: int, steps: int, window: "Window", progress: Progress) -> dict | None:
        """Log/validate/checkpoint when due; returns the logged row, None when nothing was logged."""
        o, final = self.opts, step == steps
        val_due = final or step % (o.val_every or o.ckpt_every) == 0
        row = None
        if final or val_due or step % o.log_every == 0:
            self.trained += (window.images, window.seconds())
            row = {"train_loss": window.mean_loss(), "images_per_s": window.rate(),
                   **(self.validate(step) if val_due else {})}
            self.log.row(step=step, lr=self.opt.param_groups[0]["lr"], **row)
            progress.update(step, f"fit: loss {row['train_loss']:.4f} {row['images_per_s']:.1f} img/s", force=final)
            window.reset()
        if final or step % o.ckpt_every == 0:
            with window.paused():  # keep checkpoint time out of images_per_s
                self.save(step)
        return row

    def announce(self, step: int, steps: int) -> None:
        """One stderr line saying what this run does."""
        if self.rank != 0 or self.opts.quiet:
            return
        p, cfg = self.plan, self.model.cfg
        val = f"{p.val.describe()} ({p.n_val} samples)" if p.val else "none"
        print(f"fit: {cfg.width}x{cfg.height} px, train {p.train.describe()} ({p.n_train} samples), "
              f"val {val}, steps {step}→{steps}, "
              f"batch {self.opts.batch}×{self.world}, {self.device}, autocast {self.dtype or 'off'}, "
              f"{torch.get_num_threads()} threads", file=sys.stderr)

    def validate(self, step: int) -> dict:
        """Validation loss/MAE on rank 0 ({} elsewhere or without a val set); keeps run/best.pt."""
        if self.plan.val is None:
            return {}
        val = {}
        if self.rank == 0:
            val = validate(self.model, self.val_loader(), self.device, self.dtype, self.opts.val_max)
            best = self.state.get("best_val_mae")
            if not val.pop("val_n"):
                val = {}  # an empty holdout: no numbers rather than zeros
            elif best is None or val["val_mae"] < best:
                self.state["best_val_mae"] = val["val_mae"]
                self.save(step, self.run / "best.pt")
        runtime.barrier()
        return val

    def save(self, step: int, path: Path | None = None) -> None:
        """Checkpoint (rank 0 only; no collective, so safe inside rank-0-only code), atomically replaced."""
        if self.rank != 0:
            return
        self.state.update(step=step, model=self.model.state_dict(), optimizer=self.opt.state_dict(),
                          rng=torch.get_rng_state())
        checkpoint.save(path or self.run / "last.pt", self.state)
        if path is None:
            (self.run / "config.json").write_text(json.dumps(self.state["config"], indent=1))

    def summary(self, step: int, loss: float | None, val: dict) -> dict:
        """What fit prints at the end."""
        return {"step": step, "train_loss": loss, **val, "best_val_mae": self.state.get("best_val_mae"),
                "images": self.trained.images, "images_per_s": self.trained.rate(),
                "last": str(self.run / "last.pt"),
                "best": str(self.run / "best.pt") if (self.run / "best.pt").exists() else None}


class Tally:
    """Images and seconds summed over log windows."""

    def __init__(self) -> None:
        self.images, self.seconds = 0, 0.0

    def __iadd__(self, window: tuple[int, float]) -> "Tally":
        self.images += window[0]
        self.seconds += window[1]
        return self

    def rate(self) -> float | None:
        """Images per second over everything tallied (None before the first window)."""
        return self.images / self.seconds if self.seconds > 0 else None


class Window:
    """Loss and throughput over the steps since the last log row."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self.reset()

    def reset(self) -> None:
        """Start a new window now."""
        self.loss, self.steps, self.images, self.t0 = torch.zeros((), device=self.device), 0, 0, time.perf_counter()

    def add(self, loss: torch.Tensor, images: int) -> None:
        """Count one step (its loss stays on the device: no per-step host sync)."""
        self.loss += loss
        self.steps += 1
        self.images += images

    def mean_loss(self) -> float:
        """Mean training loss of the window, averaged over ranks."""
        return runtime.mean_over_ranks(self.loss / max(self.steps, 1))

    def seconds(self) -> float:
        """Training time since the window started (paused time excluded)."""
        return time.perf_counter() - self.t0

    def rate(self) -> float:
        """Images per second (all ranks) since the window started."""
        return self.images / max(self.seconds(), 1e-9)

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Exclude the enclosed time from the rate."""
        start = time.perf_counter()
        yield
        self.t0 += time.perf_counter() - start


class Deadline:
    """A wall-clock budget that all ranks agree has passed (checked only at log steps: one collective)."""

    def __init__(self, minutes: float | None) -> None:
        self.end = None if minutes is None else time.perf_counter() + 60.0 * minutes

    def passed(self) -> bool:
        """True once any rank is past the budget."""
        if self.end is None:
            return False
        return runtime.max_over_ranks(float(time.perf_counter() > self.end)) > 0
