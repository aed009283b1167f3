"""Images/s the shard loader delivers vs images/s a training step consumes, measured in one run.

    python benchmarks/bench_train.py                      # a 348x128 build of synthetic streets in a temp folder
    python benchmarks/bench_train.py --shards demo/shards # real shards

If the loader's rate is well above the step's, training is compute-bound and more --workers won't help.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # train/, studies/: folders of the repo
from appdgen.cli import main as appdgen  # noqa: E402
from appdgen.dataset.shardset import open_shards  # noqa: E402
from train import runtime  # noqa: E402
from train.data import Selection, StreamSpec, make_loader  # noqa: E402
from train.loop import adam, train_step  # noqa: E402
from train.model import AppdNet, ModelConfig  # noqa: E402


def parse() -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shards", help="shard folder (default: synthetic 348x128 PNG shards)")
    p.add_argument("--split", default="train")
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--steps", type=int, default=10, help="timed steps (after 5 warm-up steps)")
    p.add_argument("--loader-batches", type=int, default=30, help="timed loader batches")
    p.add_argument("--precision", default="auto", choices=runtime.PRECISIONS)
    p.add_argument("--device", default="auto")
    return p.parse_args()


def synthetic_build(out: Path, frames: int = 16, samples: int = 256) -> Path:
    """A 348x128 build of synthetic streets (appdgen synth, appdgen build), all in its train split."""
    raw = out / "raw" / "train"  # split by parent folder: every sample in "train"
    appdgen(["synth", "--frames", str(frames), "--scale", "0.25", "--seed", "1", "--out", str(raw), "--quiet"],
            standalone_mode=False)
    appdgen(["build", "--calib", str(raw / "calibration.yaml"), "--images", str(raw.parent), "--split-by", "parent",
             "--samples", str(samples), "--shard-size", "64", "--out", str(out / "shards"), "--quiet"],
            standalone_mode=False)
    return out / "shards"


def rate(fn, n: int, images: int) -> float:
    """Images per second over n calls of fn, each handling `images` images."""
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return n * images / (time.perf_counter() - t)


def main() -> None:
    """Measure loader, step and loader+step rates and print them."""
    args = parse()
    device = runtime.pick_device(args.device)
    runtime.setup_threads(device)
    dtype = runtime.autocast_dtype(device, args.precision)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.shards or synthetic_build(Path(tmp))
        ss = open_shards(root)
        w, h = ss.size
        spec = StreamSpec(ss.for_split(args.split), Selection(args.split), (w, h), loop=True, shuffle=True)
        batches = iter(make_loader(spec, args.batch, args.workers))
        next(batches)  # start-up (worker fork, first shard open) is not throughput
        load_rate = rate(lambda: next(batches), args.loader_batches, args.batch)
        model = AppdNet(ModelConfig(w, h)).to(device).to(memory_format=torch.channels_last).train()
        opt = adam(model.parameters(), 1e-4)
        fixed = next(batches)
        for _ in range(5):  # oneDNN picks and caches kernels on the first few steps
            train_step(model, opt, fixed, device, dtype)
        step_rate = rate(lambda: float(train_step(model, opt, fixed, device, dtype)), args.steps, args.batch)
        both_rate = rate(lambda: float(train_step(model, opt, next(batches), device, dtype)), args.steps, args.batch)
    print(f"device {device}, {torch.get_num_threads()} threads, autocast {dtype or 'off'}, {w}x{h} px, "
          f"batch {args.batch}, workers {args.workers}")
    print(f"loader delivers   {load_rate:8.1f} images/s")
    print(f"train step takes  {step_rate:8.1f} images/s (fixed batch, compute only)")
    print(f"loader + step     {both_rate:8.1f} images/s (as fit runs)")
    bound = "loader" if load_rate < 1.2 * step_rate else "compute"
    print(f"bound by: {bound}")


if __name__ == "__main__":
    main()
