"""Geometry and sampler cost as ratios to one LANCZOS4 remap of a raw-size 3-channel image, measured in one run.

Targets (issues #3, #4): crop + maps + APPD ≤ 25 % of a remap; the sampler ≤ 10 % of a remap per accepted sample.
Also kb4's numpy maps against cv2.fisheye.initUndistortRectifyMap, which gives the same maps (tests/test_lens.py).
Run: make bench (single-threaded OpenCV).
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from appdgen import lens
from appdgen.calib.calibration import Calibration
from appdgen.geometry.appd import appd_px
from appdgen.geometry.maps import rectify
from appdgen.sampling.sampler import Sampler

KITTI_02 = Calibration(1392, 512, 959.791, 956.9251, 696.0217, 224.1806,
                       -0.3691481, 0.1968681, 0.001353473, 0.0005677587, -0.06770705)
#: One published camera per lens model (the ROS 2880x1860 rational file, TUM VI cam0, EuRoC cam0 in Basalt's
#: eucm, a double sphere fit of an EuRoC-like lens), with the max_fov a fisheye that sees past 90° needs.
MODEL_CAMERAS: dict[str, tuple[Calibration, float | None]] = {
    "radtan": (KITTI_02, None),
    "rational": (Calibration(2880, 1860, 1495.316895, 1494.778564, 1424.459106, 943.463684, 0.929988205433,
                             0.165922805667, -0.000024369263, -0.000013859207, 0.002885974478, 1.331432461739,
                             0.435830116272, 0.027607271448, model="rational"), None),
    "kb4": (Calibration(512, 512, 190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504,
                        0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202,
                        0.00020293673591811182, model="kb4"), 120.0),
    "ds": (Calibration(752, 480, 349.7, 348.9, 365.9, 249.3, model="ds", xi=-0.2, alpha=0.59), None),
    "eucm": (Calibration(752, 480, 460.76484651566466, 459.4051018049483, 365.8937161309615, 249.33499869752444,
                         model="eucm", alpha=0.5903365915227143, beta=1.127468196965374), None),
}


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


def geometry_ratio(calib: Calibration, max_fov: float | None) -> tuple[float, float]:
    """(one LANCZOS4 remap at raw size, crop + maps + APPD of one perturbed calibration) in seconds."""
    raw = np.random.default_rng(0).integers(0, 256, (calib.height, calib.width, 3), dtype=np.uint8)
    ref = rectify(calib, max_fov=max_fov)
    perturbed = calib.perturb(fx=0.05, cy=-0.02, **{calib.param_names[4]: 0.1})
    remap = best_of(lambda: cv2.remap(raw, ref.map_x, ref.map_y, cv2.INTER_LANCZOS4,
                                      borderMode=cv2.BORDER_REFLECT_101))
    return remap, best_of(lambda: appd_px(ref, rectify(perturbed, max_fov=max_fov)))


def kb4_maps(calib: Calibration, max_fov: float) -> tuple[float, float]:
    """(appdgen's kb4 maps, cv2.fisheye's maps) of the reference crop at raw size, in seconds."""
    ref = rectify(calib, max_fov=max_fov)
    new_k, size = ref.new_camera_matrix, calib.size
    ours = best_of(lambda: lens.get("kb4").maps(calib.K, calib.coeffs, new_k, size))
    theirs = best_of(lambda: cv2.fisheye.initUndistortRectifyMap(calib.K, calib.D, np.eye(3), new_k, size,
                                                                  cv2.CV_32FC1))
    return ours, theirs


def main() -> None:
    """Print per-operation times and their ratio to one remap, per lens model."""
    cv2.setNumThreads(1)
    calib = KITTI_02
    remap, geometry = geometry_ratio(calib, None)
    sampler = Sampler(calib)
    counter = iter(range(10**9))
    sample = best_of(lambda: sampler.draw(0, next(counter)), repeat=5, number=100)
    print(f"LANCZOS4 remap {calib.width}x{calib.height}x3     {remap * 1e3:7.2f} ms   (1.00)")
    print(f"crop + maps + APPD (one perturbed) {geometry * 1e3:7.2f} ms   "
          f"({geometry / remap:.3f} of a remap; target <= 0.25)")
    print(f"sampler, per accepted sample       {sample * 1e3:7.2f} ms   "
          f"({sample / remap:.3f} of a remap; target <= 0.10)")
    print("crop + maps + APPD per lens model, as a fraction of one LANCZOS4 remap at raw size (target <= 0.25):")
    for name, (camera, max_fov) in MODEL_CAMERAS.items():
        remap, geometry = geometry_ratio(camera, max_fov)
        fov = f", max_fov {max_fov:g}" if max_fov else ""
        print(f"  {name:9s} {camera.width}x{camera.height}{fov:16s} remap {remap * 1e3:7.2f} ms   "
              f"geometry {geometry * 1e3:6.2f} ms   ({geometry / remap:.3f})")
    ours, theirs = kb4_maps(*MODEL_CAMERAS["kb4"])
    print(f"kb4 maps at 512x512: numpy {ours * 1e3:.2f} ms, cv2.fisheye.initUndistortRectifyMap {theirs * 1e3:.2f} ms "
          f"({theirs / ours:.1f}x the time)")


if __name__ == "__main__":
    main()
