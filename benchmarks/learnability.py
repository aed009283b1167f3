"""Time-boxed what-if fits: held in memory, the paper's CNN (or a variant) trains on a build and reports test MAE
against the mean predictor every minute. For quick experiments on what makes APPD learnable; `python -m train fit`
is the trainer.

    python benchmarks/learnability.py SHARDS [--minutes 10] [--lr 1e-4] [--small] [--bn]

SHARDS needs `train` and `test` splits (appdgen build --split-by parent). Images are decoded once with the
trainer's own shard reader; each step is the trainer's (bf16 autocast where the CPU has it, channels_last).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
import time

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # train/, studies/: folders of the repo
import train.model as model  # noqa: E402
from train import runtime  # noqa: E402
from train.data import Selection, ShardStream, StreamSpec, open_shards  # noqa: E402
from train.loop import adam, to_input, train_step  # noqa: E402
from train.model import AppdNet, ModelConfig  # noqa: E402

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


@torch.no_grad()
def test_mae(net: AppdNet, test: dict, dtype: torch.dtype | None) -> tuple[float, float]:
    """(MAE, prediction std) in APPD % over the first TEST_MAX test samples."""
    net.eval()
    preds = []
    for i in range(0, min(len(test["label"]), TEST_MAX), 128):
        with runtime.autocast(torch.device("cpu"), dtype):
            preds.append(net(to_input({"image": test["image"][i:i + 128]}, torch.device("cpu"))).float())
    net.train()
    pred = torch.cat(preds)
    return float((pred - test["label"][:len(pred)]).abs().mean()), float(pred.std())


def main() -> None:
    """Fit for --minutes, printing a line per minute."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shards")
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--small", action="store_true", help="the released code's 4×8-filter network")
    ap.add_argument("--bn", action="store_true", help="BatchNorm after every conv")
    args = ap.parse_args()
    torch.manual_seed(0)
    device = torch.device("cpu")
    runtime.setup_threads(device)
    dtype = runtime.autocast_dtype(device, "auto")
    train, test = load(args.shards, "train"), load(args.shards, "test")
    h, w = train["image"].shape[2:]
    if args.bn:
        model.conv_block = bn_block
    net = AppdNet(ModelConfig(width=w, height=h, **(SMALL if args.small else {}))).to(memory_format=torch.channels_last)
    opt = adam(net.parameters(), args.lr)
    base = float((train["label"].mean() - test["label"][:TEST_MAX]).abs().mean())
    print(f"{len(train['label'])} train / {len(test['label'])} test images of {w}x{h}; train label variance "
          f"{float(train['label'].var()):.4f}; mean-predictor test MAE {base:.3f} %", flush=True)
    rng, start, steps, losses, next_report = np.random.default_rng(0), time.time(), 0, [], 60.0
    while time.time() - start < args.minutes * 60:
        for i in rng.permutation(len(train["label"]))[: len(train["label"]) // args.batch * args.batch].reshape(-1, args.batch):
            idx = torch.from_numpy(i)
            losses.append(float(train_step(net, opt, {"image": train["image"][idx], "label": train["label"][idx]},
                                           device, dtype)))
            steps += 1
            elapsed = time.time() - start
            if elapsed >= next_report or elapsed >= args.minutes * 60:
                mae, spread = test_mae(net, test, dtype)
                print(f"{elapsed / 60:5.1f} min  step {steps}  epoch {steps * args.batch / len(train['label']):4.1f}  "
                      f"train MSE {np.mean(losses[-50:]):.4f}  test MAE {mae:.3f} %  ratio {mae / base:.2f}  "
                      f"pred std {spread:.3f}  {steps * args.batch / elapsed:.0f} img/s", flush=True)
                next_report += 60.0
                if elapsed >= args.minutes * 60:
                    return


if __name__ == "__main__":
    main()
