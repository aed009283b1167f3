"""The project's one training loop, which every fit drives (offline shards, online pairs, the studies' arms): Adam
on MSE of the target, log rows, validation, checkpoints, a wall-clock deadline and the run's step count and resume
rule."""
from __future__ import annotations

import contextlib
import csv
import json
import math
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

import torch
import torch.nn.functional as F

from appdgen.dataset.layout import BUILD_JSON, INDEX, TARGETS
from appdgen.util.progress import Progress
from train import checkpoint, runtime
from train.errors import TrainError
from train.inference import predict, to_input
from train.options import FitOptions, Plan

LOG_COLUMNS = ("step", "train_loss", "val_loss", "val_mae", "lr", "images_per_s")


def total_steps(opts: FitOptions, n_train: int | None, world: int) -> int:
    """Optimizer steps to run: --steps, or --epochs × samples / (batch × ranks)."""
    if (opts.steps is None) == (opts.epochs is None):
        raise TrainError("give exactly one of --steps or --epochs")
    if opts.steps is not None:
        return opts.steps
    if not n_train:
        raise TrainError(f"--epochs needs the sample count ({INDEX} or {BUILD_JSON}); use --steps")
    return max(1, math.ceil(opts.epochs * n_train / (opts.batch * world)))


def resumed(run: Path, opts: FitOptions, size: tuple[int, int]) -> dict | None:
    """run/last.pt with --resume, None to start fresh; refuses to overwrite a run without --resume, and to resume
    one of the other kind (--online or --shards), on another --target or of another image size (w, h)."""
    last = run / "last.pt"
    if last.exists() and not opts.resume:
        raise TrainError(f"{last} exists: pass --resume to continue it, or choose another --run")
    if not last.exists():
        if opts.resume:
            print(f"fit: --resume but no {last}; starting fresh", file=sys.stderr)
        return None
    state = checkpoint.load(last)
    online = bool(state["config"].get("data", {}).get("online"))
    if online != (opts.online is not None):
        kind = "--online" if online else "--shards"
        raise TrainError(f"{last}: a {kind} run; resume it with {kind}, or choose another --run")
    trained = checkpoint.target(state)
    if trained != opts.target:
        raise TrainError(f"{last}: trained on --target {trained}; resume with --target {trained}, or choose another "
                         f"--run")
    cfg = checkpoint.model_config(state)
    if (cfg.width, cfg.height) != tuple(size):
        raise TrainError(f"{last} was trained on {cfg.width}x{cfg.height} images, not {size[0]}x{size[1]}")
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


def check_shapes(pred: torch.Tensor, target: torch.Tensor) -> None:
    """Refuse a prediction whose shape is not the target's: an (N, 1) prediction against an (N,) target broadcasts
    MSE over all N×N pairs, whose optimum is the batch mean (the bug the paper's authors fixed in "Fixed loss")."""
    if pred.shape != target.shape:
        raise TrainError(f"prediction shape {tuple(pred.shape)} differs from the target's {tuple(target.shape)}: "
                         "the loss would broadcast over pairs of images")


def adam(params, lr: float) -> torch.optim.Optimizer:
    """The project's one optimiser (every fit, and the benchmarks that time a step): Adam at learning rate lr."""
    return torch.optim.Adam(params, lr=lr)


def train_step(net: torch.nn.Module, opt: torch.optim.Optimizer, batch: dict, device: torch.device,
               dtype: torch.dtype | None) -> torch.Tensor:
    """One Adam step on MSE(pred, appd_pct); returns the detached loss (no host sync)."""
    x = to_input(batch, device)
    y = batch["label"].to(device, non_blocking=True)
    with runtime.autocast(device, dtype):
        pred = net(x)
    check_shapes(pred, y)
    loss = F.mse_loss(pred.float(), y)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return loss.detach()


def validate(model: torch.nn.Module, loader: Iterable[dict], device: torch.device, dtype: torch.dtype | None,
             limit: int) -> dict:
    """MSE loss and MAE (the target's %) over up to `limit` samples."""
    sq = ab = 0.0
    n = 0
    for batch, pred in predict(model, loader, device, dtype, limit):
        err = pred - batch["label"].to(device)
        sq += float((err**2).sum())
        ab += float(err.abs().sum())
        n += len(err)
    return {"val_loss": sq / max(n, 1), "val_mae": ab / max(n, 1), "val_n": n}


class Trainer:
    """The training loop and its bookkeeping for one process (rank) of a run, over any data: a kind of run (the
    offline fit's shards, the online fit's fresh pairs) gives loader, val_loader and announce. `plan` says what
    trains and validates (its `val` None when nothing does). A model without parameters (the plumb-line floor) has no
    optimiser: train.closed_form fits it, beside this loop."""

    def __init__(self, opts: FitOptions, plan: Plan, state: dict, device: torch.device, rank: int, world: int,
                 run: Path) -> None:
        self.opts, self.plan, self.state = opts, plan, state
        self.device, self.rank, self.world, self.run = device, rank, world, run
        self.dtype = runtime.autocast_dtype(device, opts.precision)
        self.model = checkpoint.build_model(state).to(device).to(memory_format=torch.channels_last).train()
        params = list(self.model.parameters())
        self.opt = adam(params, opts.lr) if params else None
        if state["optimizer"] is not None and self.opt is not None:
            self.opt.load_state_dict(state["optimizer"])
            for group in self.opt.param_groups:
                group["lr"] = opts.lr  # a resumed run takes the lr given now
        if state.get("rng") is not None:
            torch.set_rng_state(state["rng"])  # dropout continues as it would have: a resume repeats the losses
        self.net = self.model
        if world > 1 and params:  # train.closed_form refuses a closed-form model under torchrun
            from torch.nn.parallel import DistributedDataParallel

            self.net = DistributedDataParallel(self.model, device_ids=[device.index] if device.type == "cuda" else None)
        self.log = CsvLog(run / "log.csv", rank == 0)
        self.trained = Tally()  # images and seconds of training steps in this process, validation excluded
        self.size = (self.model.cfg.width, self.model.cfg.height)

    def loader(self, step: int) -> Iterator[dict]:
        """Infinite training batches ({"image": uint8 N×C×H×W, "label": APPD %}) for this rank, from where step
        `step` left the data."""
        raise NotImplementedError

    def val_loader(self) -> Iterable[dict]:
        """Validation batches (rank 0 validates alone)."""
        raise NotImplementedError

    @property
    def closed_form(self) -> bool:
        """Whether the model has no parameters to train (the plumb-line floor: train.closed_form fits it)."""
        return self.opt is None

    def finished(self, steps: int) -> dict | None:
        """The summary, said on stderr, when the checkpoint already holds `steps` steps; None when work is left."""
        step = int(self.state["step"])
        if step < steps:
            return None
        print(f"fit: checkpoint is already at step {step} ≥ {steps}; nothing to do", file=sys.stderr)
        return self.summary(step, None, {})

    def train(self, steps: int) -> dict:
        """Run until `steps` optimizer steps; log, validate, checkpoint on the way and at the end."""
        if self.closed_form:
            raise TrainError(f"--model {self.model.cfg.arch} has no parameters to train: fit it with train.closed_form")
        done = self.finished(steps)
        if done is not None:
            return done
        step = int(self.state["step"])
        self.announce(step, steps)
        progress = Progress(steps, "steps", enabled=self.rank == 0 and not self.opts.quiet, every=30.0, done=step)
        batches, window = self.loader(step), Window(self.device)
        last, deadline = {"train_loss": None}, Deadline(self.opts.max_minutes)
        while step < steps:
            batch = next(batches, None)
            if batch is None:
                raise TrainError(f"no training samples for {self.plan.training()} on rank {self.rank}")
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
        """One stderr line saying what this run does (rank 0, unless --quiet): its data (describe) and its loop."""
        if self.rank != 0 or self.opts.quiet:
            return
        cfg = self.model.cfg
        print(f"{self.describe()}, {cfg.width}x{cfg.height} px, {TARGETS[self.opts.target]}, steps {step}→{steps}, "
              f"batch {self.opts.batch}×{self.world}, {self.device}, autocast {self.dtype or 'off'}, "
              f"{torch.get_num_threads()} threads, {self.opts.workers} loader workers", file=sys.stderr)

    def describe(self) -> str:
        """'fit: train …, val …': the command and what this run trains and validates on."""
        raise NotImplementedError

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
        self.state.update(step=step, model=self.model.state_dict(),
                          optimizer=self.opt.state_dict() if self.opt is not None else None,
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
