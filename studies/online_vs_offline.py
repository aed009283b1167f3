"""Fixed pairs against fresh pairs: the same network, the same frames, the same minutes, the same unseen test set.

    python -m studies.online_vs_offline [--frames 1000] [--per-frame 8] [--test-frames 100] [--minutes 20]
                                           [--out runs/online-vs-offline] [--scale 0.25]

Synthetic car-mount KITTI 02 frames (train: one seed, test: another, so no scene is shared). Arm `offline`
trains on an offline build of the train frames × --per-frame calibrations (`fit --shards`); arm `online` on fresh
pairs of the same frames (`fit --online`, cpu render, draws in the training process). Both run at once, one core
each (torch's threads follow the process's CPU affinity), and after every minute of training evaluate the
checkpoint on the test build: test MAE / the mean predictor's MAE (1.00 = nothing learnt). Prints one table.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

ARMS = ("offline", "online")
COLUMNS = ("minute", "images", "train_loss", "test_mae", "mean_mae", "ratio", "data_wait_fraction")


def prepare(args: argparse.Namespace, out: Path) -> Path:
    """Synthesize train and test frames, build the offline arm's pairs and the test set; returns the calibration."""
    from appdgen.calib.formats import load
    from appdgen.dataset.build import build
    from appdgen.dataset.plan import BuildConfig
    from appdgen.sources.files import list_images
    from studies.experiment import ExperimentOptions, synthesize_frames

    raw = out / "raw"
    opts = ExperimentOptions(out=str(out), frames=args.frames, val_frames=1, test_frames=args.test_frames,
                             scale=args.scale, seed=args.seed)
    calib_path = synthesize_frames(opts, raw, args.jobs)
    reference = load(calib_path)
    for name, folder, per_frame, seed in (("offline", "train", args.per_frame, args.seed),
                                          ("test", "test", args.test_per_frame, 1000 + args.seed)):
        images = tuple(list_images(str(raw / folder)))
        config = BuildConfig(reference=reference, camera="02", calib_path=str(calib_path), images=images,
                             samples=per_frame * len(images), size=reference.size, seed=seed)
        build(config, out / name, args.jobs, progress=False, overwrite=True)
    (out / "calibration.txt").write_text(str(calib_path))
    return calib_path


def arm(args: argparse.Namespace, out: Path, name: str) -> None:
    """One arm: fit a minute at a time (--resume), evaluating on the test build after each; rows to OUT/NAME.csv."""
    os.sched_setaffinity(0, {args.core})  # one core: runtime.setup_threads then gives torch one thread
    from train.evaluate import evaluate
    from train.fit import FitOptions, fit
    from train.online.options import OnlineOptions

    run = out / f"run-{name}"
    common = dict(run=str(run), steps=10**9, batch=args.batch, lr=args.lr, workers=0, ckpt_every=10**9,
                  val_split="none", log_every=1, max_minutes=1.0, seed=args.seed, device="cpu", quiet=True)
    if name == "offline":
        opts = FitOptions(shards=str(out / "offline"), split="all", **common)
    else:
        online = OnlineOptions(calib=(out / "calibration.txt").read_text(), images=str(out / "raw" / "train"))
        opts = FitOptions(shards=None, split="all", online=online, **common)
    with open(out / f"{name}.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(COLUMNS)
        images = 0
        for minute in range(1, args.minutes + 1):
            summary = fit(replace(opts, resume=minute > 1))
            images += summary["images"]
            result = evaluate(summary["last"], str(out / "test"), "all", workers=0, device="cpu")
            writer.writerow([minute, images, f"{summary['train_loss']:.4f}", f"{result['mae']:.4f}",
                             f"{result['mean_predictor_mae']:.4f}", f"{result['mae_vs_mean_predictor']:.3f}",
                             "" if name == "offline" else f"{summary['data_wait_fraction']:.3f}"])
            fh.flush()


def table(out: Path) -> str:
    """Both arms' rows side by side: minute, images seen and test MAE / mean-predictor MAE of each."""
    rows = {name: list(csv.DictReader(open(out / f"{name}.csv"))) for name in ARMS}
    lines = ["| minute | offline images | offline test MAE / mean | online images | online test MAE / mean |",
             "|---:|---:|---:|---:|---:|"]
    for a, b in zip(*rows.values(), strict=False):
        lines.append(f"| {a['minute']} | {a['images']} | {a['ratio']} ({a['test_mae']} / {a['mean_mae']} %) | "
                     f"{b['images']} | {b['ratio']} ({b['test_mae']} / {b['mean_mae']} %) |")
    return "\n".join(lines)


def main() -> None:
    """Prepare the data, run both arms in parallel (one core each), print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000, help="Train frames (both arms).")
    parser.add_argument("--per-frame", type=int, default=8, help="Calibrations per frame of the offline build.")
    parser.add_argument("--test-frames", type=int, default=100)
    parser.add_argument("--test-per-frame", type=int, default=4)
    parser.add_argument("--minutes", type=int, default=20, help="Training minutes per arm.")
    parser.add_argument("--scale", type=float, default=0.25, help="KITTI 02 scale: 0.25 = 348x128.")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--lr", type=float, default=1e-4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="Processes for synth and build.")
    parser.add_argument("--out", default="runs/online-vs-offline")
    parser.add_argument("--arm", choices=ARMS, help=argparse.SUPPRESS)
    parser.add_argument("--core", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    out = Path(args.out)
    if args.arm:
        arm(args, out, args.arm)
        return
    start = time.perf_counter()
    prepare(args, out)
    print(f"prepared in {time.perf_counter() - start:.0f} s: {args.frames} train frames, offline build "
          f"{args.frames * args.per_frame} pairs, test {args.test_frames * args.test_per_frame} pairs", flush=True)
    cores = sorted(os.sched_getaffinity(0))
    passed = [a for a in sys.argv[1:]]
    procs = [subprocess.Popen([sys.executable, "-m", "studies.online_vs_offline", *passed, "--arm", name,
                               "--core", str(cores[i % len(cores)])])
             for i, name in enumerate(ARMS)]
    codes = [p.wait() for p in procs]
    if any(codes):
        sys.exit(f"an arm failed (exit {codes})")
    print(table(out))
    print(json.dumps({"command": " ".join(["python", "-m", "studies.online_vs_offline", *passed]),
                      "seconds": round(time.perf_counter() - start)}))


if __name__ == "__main__":
    main()
