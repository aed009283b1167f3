"""Time-boxed what-if fits: held in memory, the paper's CNN (or a variant) trains on a build and reports test MAE
against the mean predictor every --val-every steps. For quick experiments on what makes APPD learnable; the fit is
the trainer's one loop (train.loop.Trainer) over the split held in memory, its run in --run.

    python -m studies.learnability SHARDS [--minutes 10] [--lr 1e-4] [--small] [--bn] [--run runs/learnability]

SHARDS needs `train` and `test` splits (appdgen build --split-by parent). Images are decoded once with the
trainer's own shard reader; each step is the trainer's (bf16 autocast where the CPU has it, channels_last).
"""
from __future__ import annotations

import argparse
import csv
import shutil
from pathlib import Path

import numpy as np
import torch
from torch import nn

import train.model as model
from appdgen.dataset.shardset import open_shards
from train import checkpoint
from train.data import Selection, ShardStream, StreamSpec
from train.fit import FitOptions
from train.loop import Trainer
from train.model import ModelConfig
from train.online.trainer import OnlinePlan

#: The smaller network of the paper's released code (4 blocks of 8 filters, dense 256 → 64): ~14× fewer FLOPs.
SMALL = dict(filters=(8, 8, 8, 8), dense=(256, 64))
TEST_MAX = 512  # test images scored each minute


def load(root: str, split: str) -> dict:
    """All samples of a split as one batch dict: uint8 N×3×H×W images and float32 labels (APPD %)."""
    ss = open_shards(root)
    items = list(ShardStream(StreamSpec(ss.for_split(split), Selection(split), ss.size)))
    return {"image": torch.stack([s["image"] for s in items]), "label": torch.stack([s["label"] for s in items])}


def bn_block(c_in: int, c_out: int) -> nn.Sequential:
    """The paper's block with BatchNorm after each conv (not in the paper; a trainability probe)."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True), nn.MaxPool2d(2),
    )


class MemoryTrainer(Trainer):
    """The trainer's loop over a split held in memory (shuffled epochs), validating on the first TEST_MAX test
    images."""

    def __init__(self, opts: FitOptions, train: dict, test: dict, state: dict, run: Path) -> None:
        n_test = min(len(test["label"]), TEST_MAX)
        plan = OnlinePlan(f"{len(train['label'])} images in memory", f"{n_test} test images", len(train["label"]),
                          n_test)
        super().__init__(opts, plan, state, torch.device("cpu"), 0, 1, run)
        self.data, self.test = train, test

    def loader(self, step: int):
        """Shuffled batches of the training split, epoch after epoch (seeded; a whole number of batches each)."""
        rng, n, b = np.random.default_rng(step), len(self.data["label"]), self.opts.batch
        while True:
            for i in rng.permutation(n)[: n // b * b].reshape(-1, b):
                idx = torch.from_numpy(i)
                yield {"image": self.data["image"][idx], "label": self.data["label"][idx]}

    def val_loader(self):
        """The first TEST_MAX test images in batches of 128."""
        return [{k: v[i:min(i + 128, TEST_MAX)] for k, v in self.test.items()}
                for i in range(0, min(len(self.test["label"]), TEST_MAX), 128)]

    def describe(self) -> str:
        """'learnability: train …, val …'."""
        return f"learnability: train {self.plan.train}, val {self.plan.val}"


def main() -> None:
    """Fit for --minutes, then print the log's validated rows (test MAE vs the mean predictor)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shards")
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--val-every", type=int, default=100, help="steps between test MAE rows")
    ap.add_argument("--run", default="runs/learnability", help="run folder (replaced)")
    ap.add_argument("--small", action="store_true", help="the released code's 4×8-filter network")
    ap.add_argument("--bn", action="store_true", help="BatchNorm after every conv")
    args = ap.parse_args()
    train, test = load(args.shards, "train"), load(args.shards, "test")
    h, w = train["image"].shape[2:]
    if args.bn:
        model.conv_block = bn_block
    run = Path(args.run)
    shutil.rmtree(run, ignore_errors=True)
    run.mkdir(parents=True)
    opts = FitOptions(shards=None, run=str(run), steps=10**9, batch=args.batch, lr=args.lr, ckpt_every=10**9,
                      val_every=args.val_every, val_max=TEST_MAX, log_every=args.val_every, max_minutes=args.minutes,
                      device="cpu")
    state = checkpoint.initial(ModelConfig(width=w, height=h, **(SMALL if args.small else {})), 0,
                               {"study": "learnability", "shards": args.shards})
    base = float((train["label"].mean() - test["label"][:TEST_MAX]).abs().mean())
    print(f"{len(train['label'])} train / {len(test['label'])} test images of {w}x{h}; train label variance "
          f"{float(train['label'].var()):.4f}; mean-predictor test MAE {base:.3f} %", flush=True)
    MemoryTrainer(opts, train, test, state, run).train(opts.steps)
    with open(run / "log.csv", newline="") as fh:
        for row in csv.DictReader(fh):
            if row["val_mae"]:
                mae = float(row["val_mae"])
                print(f"step {row['step']}  epoch {int(row['step']) * args.batch / len(train['label']):4.1f}  "
                      f"train MSE {float(row['train_loss']):.4f}  test MAE {mae:.3f} %  ratio {mae / base:.2f}  "
                      f"{float(row['images_per_s'] or 0):.0f} img/s", flush=True)


if __name__ == "__main__":
    main()
