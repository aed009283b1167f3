"""Images/s of the two renderers on one CPU core: cv2.remap with rectify()'s maps (build's renderer, LANCZOS4 and
CUBIC) and train.warp's grid_sample bicubic on CPU torch, at 348×128 and 1392×512 from KITTI 02's 1392×512 frames.

"fresh Θm" computes each image's maps from its own sampled calibration and crop (what online training does:
rectify(calib, size, crop) then cv2.remap; or rectify_batch on a batch); "maps reused" renders through maps made
beforehand (an offline bank of maps). The draws and their crops are made before timing (the sampler's cost is
bench_geometry's). Ratios are to cv2 LANCZOS4 with fresh Θm at the same size, measured in the same run. The last
row at 348×128 (a CPU fit's size) is what the renderers feed: one Adam step of the paper's CNN on the same core.
Run: python benchmarks/bench_render.py [--batch 16] [--repeat 3]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from appdgen.calib.defaults import default_calibration
from appdgen.geometry.crop import valid_region
from appdgen.geometry.maps import rectify
from appdgen.sampling.sampler import Sampler

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # train/, studies/: folders of the repo
from train.loop import adam, train_step  # noqa: E402
from train.model import AppdNet, ModelConfig  # noqa: E402
from train.warp import maps_batch, rectify_batch, remap_batch  # noqa: E402

SIZES = ((348, 128), (1392, 512))


def per_image(fn, images: int, repeat: int) -> float:
    """Best seconds per image over `repeat` rounds of fn() (which renders `images` images), after one warm-up."""
    fn()
    rounds = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        rounds.append((time.perf_counter() - start) / images)
    return min(rounds)


def main() -> None:
    """Print images/s per renderer, size and map policy, and each one's ratio to cv2 LANCZOS4 with fresh maps."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=16, help="images per round (and per device batch)")
    parser.add_argument("--repeat", type=int, default=3, help="rounds; the best one counts")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    calib, n, cpu = default_calibration("02"), args.batch, torch.device("cpu")
    sampler = Sampler(calib)
    calibs = [sampler.draw(0, i).calib for i in range(n)]
    crops = [valid_region(c) for c in calibs]
    rng = np.random.default_rng(0)
    frames = [cv2.GaussianBlur(rng.integers(0, 256, (calib.height, calib.width, 3), dtype=np.uint8), (0, 0), 1.5)
              for _ in range(n)]
    batch = torch.from_numpy(np.stack(frames)).permute(0, 3, 1, 2).contiguous()
    print(f"one core (cv2.setNumThreads(1), torch.set_num_threads(1)); {n} images per round, best of {args.repeat}; "
          f"raw {calib.width}x{calib.height}x3 uint8")
    print(f"{'renderer':34s} {'size':>9s} {'maps':>11s} {'ms/image':>9s} {'images/s':>9s} {'ratio':>6s}")
    for size in SIZES:
        new_ks = [k.camera_matrix(size) for k in crops]
        rects = [rectify(c, size, crop=k) for c, k in zip(calibs, crops, strict=True)]

        def cv2_fresh(flag: int) -> None:
            for frame, c, k in zip(frames, calibs, crops, strict=True):
                r = rectify(c, size, crop=k)
                cv2.remap(frame, r.map_x, r.map_y, flag, borderMode=cv2.BORDER_REFLECT_101)

        def cv2_reused(flag: int) -> None:
            for frame, r in zip(frames, rects, strict=True):
                cv2.remap(frame, r.map_x, r.map_y, flag, borderMode=cv2.BORDER_REFLECT_101)

        map_x, map_y = maps_batch(calibs, new_ks, size)
        floats = batch.float()
        net = AppdNet(ModelConfig(*size)).to(memory_format=torch.channels_last).train()
        opt = adam(net.parameters(), 1e-4)
        step = {"image": remap_batch(batch, map_x, map_y), "label": torch.rand(n)}
        for _ in range(3):  # oneDNN picks and caches its kernels on the first steps
            train_step(net, opt, step, cpu, None)
        runs = {
            ("cv2.remap LANCZOS4", "fresh Θm"): lambda: cv2_fresh(cv2.INTER_LANCZOS4),
            ("cv2.remap LANCZOS4", "reused"): lambda: cv2_reused(cv2.INTER_LANCZOS4),
            ("cv2.remap CUBIC", "fresh Θm"): lambda: cv2_fresh(cv2.INTER_CUBIC),
            ("cv2.remap CUBIC", "reused"): lambda: cv2_reused(cv2.INTER_CUBIC),
            ("grid_sample bicubic, CPU torch", "fresh Θm"): lambda: rectify_batch(batch, calibs, new_ks, size),
            ("grid_sample bicubic, CPU torch", "reused"): lambda: remap_batch(batch, map_x, map_y),
            ("grid_sample bicubic, float frames", "reused"): lambda: remap_batch(floats, map_x, map_y),
            ("  its maps alone (maps_batch)", "fresh Θm"): lambda: maps_batch(calibs, new_ks, size),
        }
        if size == SIZES[0]:
            runs[("train step, AppdNet (consumes)", "-")] = lambda: float(train_step(net, opt, step, cpu, None))
        base = None
        for (name, maps), fn in runs.items():
            seconds = per_image(fn, n, args.repeat)
            base = base or seconds
            print(f"{name:34s} {size[0]:>4d}x{size[1]:<4d} {maps:>11s} {seconds * 1e3:9.2f} {1 / seconds:9.0f} "
                  f"{base / seconds:6.2f}")


if __name__ == "__main__":
    main()
