"""A build from a recording against the same build from its frames exported as PNGs (issue 20, item 3).

The same KITTI-size frames (blurred noise) are written as PNGs, a ROS 1 bag (bgr8 Image), a ROS 2 mcap bag of
JPEG CompressedImages, and an mp4 video; each source is built with the same options, alternating over --rounds,
and the ratio PNG-build time / recording-build time is printed (target >= 0.8: indexing once in the parent and
reading each shard's frames in one pass must cost about what decoding PNGs does). The JPEG bag and the video are
lossy, so their samples differ from the PNGs' but cost the same to make. Wall time of the whole command (process
start, index, hash, build) from `time.perf_counter` around a subprocess.
Run: python benchmarks/bench_recordings.py [--frames 40] [--samples 400] [--jobs 2] [--rounds 3]
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


def main() -> None:
    """Write the sources, build each over the rounds, print medians and ratios."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
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
