"""Geometry and sampler cost as ratios to one LANCZOS4 remap of a raw-size 3-channel image, measured in one run.

Targets (issues #3, #4): crop + maps + APPD ≤ 25 % of a remap; the sampler ≤ 10 % of a remap per accepted sample.
Run: make bench (single-threaded OpenCV).
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from appdgen.appd import appd_px
from appdgen.calibration import Calibration
from appdgen.maps import rectify
from appdgen.sampling import Sampler

KITTI_02 = Calibration(1392, 512, 959.791, 956.9251, 696.0217, 224.1806,
                       -0.3691481, 0.1968681, 0.001353473, 0.0005677587, -0.06770705)


def best_of(fn, repeat: int = 5, number: int = 10) -> float:
    """Best mean seconds per call over `repeat` rounds of `number` calls (robust to a busy machine)."""
    fn()
    rounds = []
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        rounds.append((time.perf_counter() - start) / number)
    return min(rounds)


def main() -> None:
    """Print per-operation times and their ratio to one remap."""
    cv2.setNumThreads(1)
    calib = KITTI_02
    raw = np.random.default_rng(0).integers(0, 256, (calib.height, calib.width, 3), dtype=np.uint8)
    ref = rectify(calib)
    perturbed = calib.perturb(fx=0.05, cy=-0.02, k1=0.1)
    remap = best_of(lambda: cv2.remap(raw, ref.map_x, ref.map_y, cv2.INTER_LANCZOS4,
                                      borderMode=cv2.BORDER_REFLECT_101))
    geometry = best_of(lambda: appd_px(ref, rectify(perturbed)))
    sampler = Sampler(calib)
    counter = iter(range(10**9))
    sample = best_of(lambda: sampler.draw(0, next(counter)), repeat=5, number=100)
    print(f"LANCZOS4 remap {calib.width}x{calib.height}x3     {remap * 1e3:7.2f} ms   (1.00)")
    print(f"crop + maps + APPD (one perturbed) {geometry * 1e3:7.2f} ms   ({geometry / remap:.3f} of a remap; target <= 0.25)")
    print(f"sampler, per accepted sample       {sample * 1e3:7.2f} ms   ({sample / remap:.3f} of a remap; target <= 0.10)")


if __name__ == "__main__":
    main()
