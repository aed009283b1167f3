"""A build from a recording against the same build from its frames exported as PNGs (issue 20, item 3).

The same KITTI-size frames (blurred noise) are written as PNGs, a ROS 1 bag (bgr8 Image), a ROS 2 mcap bag of
JPEG CompressedImages, and an mp4 video; each source is built with the same options, alternating over --rounds,
and the ratio PNG-build time / recording-build time is printed (target >= 0.8: indexing once in the parent and
reading each shard's frames in one pass must cost about what decoding PNGs does). The JPEG bag and the video are
lossy, so their samples differ from the PNGs' but cost the same to make. Wall time of the whole command (process
start, index, hash, build) from `time.perf_counter` around a subprocess.
--predict-rss: peak RSS of `python -m train predict` over a mono bag of N and 4N frames (348x128, a 1-step
checkpoint): flat when predict streams (nothing held per frame but the running-median window).
Run: python benchmarks/bench_recordings.py [--frames 40] [--samples 400] [--jobs 2] [--rounds 3]
     python benchmarks/bench_recordings.py --predict-rss [--frames 500]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from appdgen.calib.defaults import DEFAULT_CALIB_PATH
from appdgen.calib.formats import load
from appdgen.synth.recording import write_bag, write_video


def frames(count: int, size: tuple[int, int]) -> list[np.ndarray]:
    """Textured frames (blurred noise compresses like real images do, roughly)."""
    rng = np.random.default_rng(0)
    return [cv2.GaussianBlur((rng.random((size[1], size[0], 3)) * 255).astype(np.uint8), (0, 0), 2.0)
            for _ in range(count)]


def timed_build(images: Path, out: Path, samples: int, jobs: int) -> float:
    """Seconds of one `appdgen build` (KITTI camera 02, 348x128 samples) from `images` into a fresh `out`."""
    command = [sys.executable, "-m", "appdgen.cli", "build", "--calib", str(DEFAULT_CALIB_PATH), "--camera", "02",
               "--images", str(images), "--out", str(out), "--samples", str(samples), "--size", "348x128",
               "--jobs", str(jobs), "--quiet", "--overwrite"]
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": os.getcwd()})
    return time.perf_counter() - start


def predict_rss(count: int) -> None:
    """Print predict's peak RSS (MB) and time over a mono bag of `count` and 4 x `count` frames."""
    from appdgen.synth.recording import write_bag

    env = {**os.environ, "PYTHONPATH": os.getcwd()}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        calib = root / "calib.yaml"
        subprocess.run([sys.executable, "-m", "appdgen.cli", "synth", "--frames", "2", "--scale", "0.25", "--out",
                        str(root / "raw"), "--quiet"], check=True, env=env)
        calib = root / "raw" / "calibration.yaml"
        subprocess.run([sys.executable, "-m", "appdgen.cli", "build", "--calib", str(calib), "--images",
                        str(root / "raw"), "--channels", "1", "--samples", "8", "--out", str(root / "shards"),
                        "--quiet"], check=True, env=env)
        subprocess.run([sys.executable, "-m", "train", "fit", "--shards", str(root / "shards"), "--split", "all",
                        "--val-split", "none", "--run", str(root / "run"), "--steps", "1", "--batch", "4",
                        "--workers", "0", "--stats-samples", "8", "--quiet"], check=True, env=env,
                       stdout=subprocess.DEVNULL)
        size = load(calib).size
        base = cv2.cvtColor(frames(1, size)[0], cv2.COLOR_BGR2GRAY)
        for n in (count, 4 * count):
            bag = root / f"run{n}.bag"
            write_bag(bag, (np.roll(base, i, axis=1) for i in range(n)))
            start = time.perf_counter()
            # The child reports its own peak (RUSAGE_CHILDREN would be the largest of every child so far).
            code = ("import resource, sys; from train.cli import main\ntry: main(sys.argv[1:])\nfinally: print("
                    "resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)")
            done = subprocess.run([sys.executable, "-c", code, "predict", "--ckpt", str(root / "run" / "last.pt"),
                                   "--calib", str(calib), str(bag)], check=True, env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, text=True)
            peak = int(done.stderr.split()[-1]) / 1024
            print(f"predict over {n:6d} frames ({bag.stat().st_size / 1e6:6.1f} MB bag): peak RSS {peak:6.1f} MB, "
                  f"{time.perf_counter() - start:.1f} s")


def main() -> None:
    """Write the sources, build each over the rounds, print medians and ratios."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--predict-rss", action="store_true")
    args = parser.parse_args()
    if args.predict_rss:
        predict_rss(args.frames)
        return
    size = load(DEFAULT_CALIB_PATH, "02").size
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        shots = frames(args.frames, size)
        (root / "png").mkdir()
        for i, shot in enumerate(shots):
            cv2.imwrite(str(root / "png" / f"{i:06d}.png"), shot)
        write_bag(root / "run.bag", shots)
        write_bag(root / "jpeg", shots, kind="mcap", compressed="jpeg")
        write_video(root / "run.mp4", shots)
        sources = {"png folder": root / "png", "ROS 1 bag (bgr8)": root / "run.bag",
                   "ROS 2 mcap (jpeg)": root / "jpeg", "mp4 video": root / "run.mp4"}
        timed_build(root / "png", root / "warm", 8, 1)  # first run pays the imports' disk reads
        seconds: dict[str, list[float]] = {name: [] for name in sources}
        for _ in range(args.rounds):
            for name, path in sources.items():
                seconds[name].append(timed_build(path, root / "out", args.samples, args.jobs))
    base = statistics.median(seconds["png folder"])
    print(f"{args.frames} frames {size[0]}x{size[1]}, {args.samples} samples at 348x128, --jobs {args.jobs}, "
          f"median of {args.rounds} rounds")
    for name, times in seconds.items():
        median = statistics.median(times)
        print(f"  {name:18s} {median:6.2f} s   png time / this = {base / median:.2f}  (target >= 0.8)")


if __name__ == "__main__":
    main()
