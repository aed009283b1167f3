"""`fit`: stream shards, train the paper's CNN on APPD (% of diagonal) with MSE, checkpoint, validate."""
from __future__ import annotations

import dataclasses
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from appdgen.dataset.layout import BUILD_JSON, INDEX, TARGETS
from appdgen.dataset.shardset import ShardSet, open_shards, read_labels, target_labels
from train import checkpoint, runtime
from train.closed_form import fit_closed_form
from train.data import Selection, ShardStream, StreamSpec, channel_stats, count_selected, make_loader
from train.errors import TrainError
from train.holdout import holdout_unit, val_choice
from train.loop import Trainer, resumed, total_steps
from train.model import check_size
from train.options import FitOptions

#: Options that fix the order samples arrive in; a resume with the same ones continues the data exactly.
RESUME_SAME = ("batch", "workers", "seed", "shuffle_buffer")


@dataclass(frozen=True)
class DataPlan:
    """Train and validation selections and their sizes (None when unknown), and the labels they are read with
    (key → the --target's label; None: the json members' appd_pct)."""

    train: Selection
    val: Selection | None
    n_train: int | None
    n_val: int | None
    labels: Mapping[str, float] | None = None

    def training(self) -> str:
        """What trains, in words (the Plan protocol)."""
        return self.train.describe()


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
    val_split = val_choice(opts.val_split, ss.split_count("val") > 0)
    if val_split == "none":
        return DataPlan(Selection(opts.split), None, _known_count(ss, labels, Selection(opts.split)), None)
    if val_split != "holdout":
        if ss.split_count(val_split) == 0:
            raise TrainError(f"{ss.root}: --val-split {val_split!r} has no samples")
        train, val = Selection(opts.split), Selection(val_split)
    else:
        by, held = holdout_unit(labels, opts.split, opts.val_by, opts.val_fraction)
        raw = dict(zip(labels["key"], labels["raw_path"], strict=True)) if labels else None
        if raw is None:
            print(f"fit: no {INDEX}; holding out by each sample's json raw_path, else its key", file=sys.stderr)
        train = Selection(opts.split, opts.val_fraction, "train", raw, by, held)
        val = Selection(opts.split, opts.val_fraction, "val", raw, by, held)
    return DataPlan(train, val, _known_count(ss, labels, train), _known_count(ss, labels, val))


def _known_count(ss: ShardSet, labels: dict | None, sel: Selection) -> int | None:
    """Size of a selection from labels.parquet, or from build.json when no holdout applies."""
    n = count_selected(labels, sel)
    if n is None and sel.holdout <= 0 and ss.build:
        n = ss.split_count(sel.split)
    return n


def sample_size(ss: ShardSet, sel: Selection) -> tuple[int, int]:
    """Image size (w, h) from build.json, else from the first sample."""
    if ss.size is not None:
        return (int(ss.size[0]), int(ss.size[1]))
    first = next(iter(ShardStream(StreamSpec(ss.for_split(sel.split), sel, limit=1))), None)
    if first is None:
        raise TrainError(f"{ss.root}: no samples for {sel.describe()}")
    _, h, w = first["image"].shape
    return (w, h)


def new_state(ss: ShardSet, labels: dict | None, plan: DataPlan, opts: FitOptions, size: tuple[int, int]) -> dict:
    """A fresh checkpoint dict for images of `size` (w, h): normalisation from a spread subset, label mean, untrained
    weights."""
    check_size(*size)
    checkpoint.check_normalize(opts.normalize)
    spec = StreamSpec(ss.for_split(plan.train.split), plan.train, size, labels=plan.labels)
    mean, std, sub_labels, mean_image = channel_stats(spec, opts.stats_samples, plan.n_train)
    label_mean = (_train_label_mean(labels, plan.train, TARGETS[opts.target]) if labels
                  else sum(sub_labels) / len(sub_labels))
    channels = "grey" if len(mean) == 1 else "bgr"  # the build's samples: 1 channel from a mono source
    return checkpoint.fresh(opts, size, (mean, std, mean_image), channels, {
        "label_mean": label_mean, "appd_max": ss.appd_max,
        "rectify": ss.rectify_rule(),  # predict --calib rectifies raw images by the same rule
        "data": {"shards": str(ss.root), "train": plan.train.describe(),
                 "val": plan.val.describe() if plan.val else None, "n_train": plan.n_train, "n_val": plan.n_val}})


def _train_label_mean(labels: dict, sel: Selection, column: str) -> float:
    """Mean label (`column`, e.g. appd_pct) over a selection's rows of labels.parquet (exact, no image decoding)."""
    vals = [a for k, s, r, a in zip(labels["key"], labels["split"], labels["raw_path"], labels[column], strict=True)
            if sel.accepts({"key": k, "split": s, "raw_path": r})]
    return sum(vals) / len(vals)


def load_or_init(ss: ShardSet, labels: dict | None, plan: DataPlan, opts: FitOptions, run: Path) -> dict:
    """The checkpoint to start from: run/last.pt with --resume, else a fresh one (never overwrites)."""
    size = sample_size(ss, plan.train)
    state = resumed(run, opts, size)
    if state is None:
        return new_state(ss, labels, plan, opts, size)
    last = run / "last.pt"
    started = state["config"].get("fit", {})
    changed = [k for k in RESUME_SAME if k in started and started[k] != getattr(opts, k)]
    if changed:
        print(f"fit: resuming with another {', '.join('--' + k.replace('_', '-') for k in changed)} than the run "
              f"started with: the data continues from an approximate position", file=sys.stderr)
    mismatch = checkpoint.rule_mismatch(state, ss.rectify_rule())
    if mismatch:
        raise TrainError(f"{last}: {mismatch}; resume on shards built with the same --max-fov, or start a new --run")
    return state


def fit(opts: FitOptions) -> dict | None:
    """Train to the requested step count; rank 0 returns a summary (step, losses, checkpoint paths)."""
    device = runtime.pick_device(opts.device)
    runtime.setup_threads(device)
    runtime.init_distributed(device)
    rank, world = runtime.rank(), runtime.world_size()
    run = Path(opts.run)
    if opts.online is not None:
        from train.online.trainer import online_trainer

        trainer, steps = online_trainer(opts, device, rank, world, run)
    else:
        trainer, steps = shard_trainer(opts, device, rank, world, run)
    try:
        summary = fit_closed_form(trainer, steps) if trainer.closed_form else trainer.train(steps)
    finally:
        runtime.finish_distributed()
    return summary if rank == 0 else None


def shard_trainer(opts: FitOptions, device: torch.device, rank: int, world: int, run: Path) -> tuple[Trainer, int]:
    """(the Trainer of a run on an offline build, its total steps)."""
    if not opts.shards:
        raise TrainError("give --shards (a build folder), or --online with --calib and --images")
    ss = open_shards(opts.shards)
    opts = only_split(ss, opts)
    labels = read_labels(ss.root, opts.target)
    plan = dataclasses.replace(plan_data(ss, labels, opts), labels=target_labels(labels, opts.target))
    steps = total_steps(opts, plan.n_train, world)
    if rank == 0:
        run.mkdir(parents=True, exist_ok=True)
    state = load_or_init(ss, labels, plan, opts, run)
    return ShardTrainer(opts, ss, plan, state, device, rank, world, run), steps


class ShardTrainer(Trainer):
    """The training loop on an offline build's shards."""

    def __init__(self, opts: FitOptions, ss: ShardSet, plan: DataPlan, state: dict, device: torch.device,
                 rank: int, world: int, run: Path) -> None:
        super().__init__(opts, plan, state, device, rank, world, run)
        self.ss = ss

    def loader(self, step: int):
        """Infinite shuffled training batches for this rank, from where step `step` left the data."""
        spec = StreamSpec(self.ss.for_split(self.plan.train.split), self.plan.train, self.size, loop=True,
                          shuffle=True, seed=self.opts.seed, buffer=self.opts.shuffle_buffer, rank=self.rank,
                          world=self.world, skip_batches=step, batch=self.opts.batch, labels=self.plan.labels)
        return iter(make_loader(spec, self.opts.batch, self.opts.workers))

    def val_loader(self):
        """Validation batches in shard order (rank 0 validates alone)."""
        sel = self.plan.val
        spec = StreamSpec(self.ss.for_split(sel.split), sel, self.size, labels=self.plan.labels)
        return make_loader(spec, self.opts.batch, self.opts.workers)

    def describe(self) -> str:
        """'fit: train …, val …' of the shards."""
        p = self.plan
        val = f"{p.val.describe()} ({p.n_val} samples)" if p.val else "none"
        return f"fit: train {p.train.describe()} ({p.n_train} samples), val {val}"
