"""What the bend columns cost a build: split_warp per sample against the rest of a sample (draw, remap, encode).

    python benchmarks/bench_bend.py [--size 1392x512] [--samples 40]

Times each stage of a build's worker on the bundled KITTI camera 02 (a random raw image, PNG, bilinear), per
sample in one run, and prints split_warp's share; the best of three repeats for split_warp (it is sub-millisecond,
so one scheduler hiccup would dominate it on a loaded machine).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from appdgen.calib.defaults import default_calibration
from appdgen.dataset.images import encode_image
from appdgen.dataset.worker import warp_columns
from appdgen.geometry.remap import remap_image
from appdgen.sampling.options import SamplingOptions


def seconds(call, repeats: int = 1) -> float:
    """The best of `repeats` wall times of call(), seconds."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    """Print per-sample milliseconds per stage and split_warp's share of a sample."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1392x512", help="output size WxH (default: KITTI's full raw size)")
    parser.add_argument("--samples", type=int, default=40)
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    reference = default_calibration()
    sampler = SamplingOptions().sampler(reference, size)
    raw = np.random.default_rng(0).integers(0, 256, (reference.height, reference.width, 3), dtype=np.uint8)
    spent = dict.fromkeys(("draw", "split_warp", "remap", "encode"), 0.0)
    for index in range(args.samples):
        draw = None

        def sample() -> None:
            nonlocal draw
            draw = sampler.draw(0, index)

        spent["draw"] += seconds(sample)
        crop = sampler.reference_rect.crop
        spent["split_warp"] += seconds(lambda: warp_columns(reference, crop, draw.calib, draw.rect.crop), 3)
        image = None

        def remap() -> None:
            nonlocal image
            image = remap_image(raw, draw.rect, "linear")

        spent["remap"] += seconds(remap)
        spent["encode"] += seconds(lambda: encode_image(image, ".png"))
    per = {k: 1e3 * v / args.samples for k, v in spent.items()}
    print(f"{args.size}, {args.samples} samples, ms per sample: "
          + ", ".join(f"{k} {v:.2f}" for k, v in per.items()))
    rest = per["draw"] + per["remap"] + per["encode"]
    print(f"split_warp = {per['split_warp'] / rest:.1%} of the rest of a sample (draw + remap + encode)")


if __name__ == "__main__":
    main()
