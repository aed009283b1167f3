"""Build throughput against its floor, measured in one run (issues #4 item 8, #13 items 1, 6 and 9).

floor   = LANCZOS4 remap + PNG encode of the same raw images at the same output size (what any generator pays);
jobs 1  = `appdgen build --jobs 1` samples/s, default shard size: target >= 0.9 x floor (sampling, maps, APPD,
          IO <= 10 %); floor and build alternate over --rounds and medians are printed, and the build's own
          stage timings give the same ratio from inside one run (the floor's work over the build's time);
jobs 2  = `--jobs 2`, default shard size (from --samples alone): target >= 1.7 x jobs 1;
check   = the reachability check a build runs before touching --out (KITTI camera 02, paper's ranges);
--rss   = peak RSS per worker over a 10,000-sample build at 348x128, and whether it grows.
Both builds and the floor run warm (a 4-sample build first pays the one-time imports, e.g. pyarrow's pandas).
Run: make bench   (or: python benchmarks/bench_build.py [--samples 120] [--size 1392x512] [--rounds 3] [--rss])
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from appdgen.dataset.build import BuildConfig, build
from appdgen.calib.calibration import Calibration
from appdgen.dataset.images import encode_image
from appdgen.dataset.layout import FORMATS
from appdgen.geometry.maps import rectify
from appdgen.sampling.sampler import Sampler
from appdgen.sources.files import list_images

KITTI_02 = Calibration(1392, 512, 959.791, 956.9251, 696.0217, 224.1806,
                       -0.3691481, 0.1968681, 0.001353473, 0.0005677587, -0.06770705)


def make_raw(folder: Path, count: int) -> None:
    """Textured raw frames (blurred noise compresses like real images do, roughly)."""
    rng = np.random.default_rng(0)
    for i in range(count):
        noise = (rng.random((KITTI_02.height, KITTI_02.width, 3)) * 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"frame_{i:04d}.png"), cv2.GaussianBlur(noise, (0, 0), 2.0))


def floor_rate(raw_dir: Path, samples: int, size: tuple[int, int]) -> tuple[float, float]:
    """Samples/s of remap + encode alone (reference maps, one decode per image as the build does): by the wall
    clock and by this process's CPU time."""
    cv2.setNumThreads(1)
    rect = rectify(KITTI_02, size)
    images = sorted(raw_dir.glob("*.png"))
    start, cpu = time.perf_counter(), time.process_time()
    for index in range(samples):
        if index % (samples // len(images)) == 0:
            raw = cv2.imread(str(images[index * len(images) // samples]))
        encode_image(cv2.remap(raw, rect.map_x, rect.map_y, cv2.INTER_LANCZOS4,
                               borderMode=cv2.BORDER_REFLECT_101), FORMATS["png"])
    return samples / (time.perf_counter() - start), samples / (time.process_time() - cpu)


def build_rate(raw_dir: Path, out: Path, samples: int, size: tuple[int, int], jobs: int) -> tuple[float, float, dict]:
    """Samples/s of a whole build with the default shard size (config and reachability check included): by the
    wall clock and by this process's CPU time (meaningful for --jobs 1, which runs in this process); and the
    build's own split of its wall time (build.json's stage_seconds, plus "other": set-up, index, build.json)."""
    shutil.rmtree(out, ignore_errors=True)  # into a fresh --out: deleting the last run's shards is not building
    start, cpu = time.perf_counter(), time.process_time()
    config = BuildConfig(KITTI_02, "02", "kitti", tuple(list_images(str(raw_dir))), samples, size)
    stages = build(config, out, jobs=jobs, overwrite=True, progress=False)["timings"]["stage_seconds"]
    wall = time.perf_counter() - start
    split = {**stages, "other": wall - sum(stages.values())}
    return samples / wall, samples / (time.process_time() - cpu), split


def reachability_seconds(size: tuple[int, int]) -> tuple[float, float]:
    """Seconds of the reachability check a build runs before --out is touched, and of the full search for the
    largest APPD it runs when no quick ray reaches --appd-max (best of 3 each, sampler set-up included)."""
    quick = full = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        Sampler(KITTI_02, size=size).check_reachable()
        quick = min(quick, time.perf_counter() - start)
        start = time.perf_counter()
        Sampler(KITTI_02, size=size).reach()
        full = min(full, time.perf_counter() - start)
    return quick, full


def rss_profile(raw_dir: Path, out: Path, samples: int) -> None:
    """Peak and progression of worker RSS over a --jobs 2 build at 348x128, polled from /proc."""
    cmd = [sys.executable, "-m", "appdgen.cli", "build", "--calib", str(raw_dir / "calib.yaml"), "--images",
           str(raw_dir), "--out", str(out), "--samples", str(samples), "--size", "348x128", "--jobs", "2",
           "--shard-size", "500", "--overwrite", "--quiet"]
    from appdgen.calib.formats import save

    save(KITTI_02, raw_dir / "calib.yaml")
    proc = subprocess.Popen(cmd)
    peaks: dict[int, list[float]] = {}
    while proc.poll() is None:
        for pid in _descendants(proc.pid):
            rss = _rss_mb(pid)
            if rss:
                peaks.setdefault(pid, []).append(rss)
        time.sleep(0.5)
    for pid, series in peaks.items():
        at = [series[min(len(series) - 1, int(f * len(series)))] for f in (0.25, 0.5, 0.75, 1.0)]
        print(f"  pid {pid}: peak {max(series):6.1f} MB; at 25/50/75/100 % of the run "
              f"{' / '.join(f'{v:.1f}' for v in at)} MB over {len(series) / 2:.0f} s")


def _descendants(pid: int) -> list[int]:
    """pid and its child processes, from /proc."""
    children = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout.split()
    return [pid] + [d for c in children for d in _descendants(int(c))]


def _rss_mb(pid: int) -> float | None:
    """Resident set size of a process in MB, or None when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def main() -> None:
    """Measure and print rates and ratios."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=120)
    parser.add_argument("--size", default="1392x512")
    parser.add_argument("--rounds", type=int, default=3,
                        help="floor and --jobs 1 build measured alternately this many times; medians are printed")
    parser.add_argument("--rss", action="store_true", help="also profile worker RSS over 10,000 samples")
    parser.add_argument("--rss-only", action="store_true", help="only profile worker RSS")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        raw, out = Path(tmp) / "raw", Path(tmp) / "out"
        raw.mkdir()
        make_raw(raw, 8)
        if args.rss_only:
            rss_profile(raw, out, 10_000)
            return
        build_rate(raw, out, 4, size, 1)  # warm-up: one-time imports
        # Alternating rounds: this machine's speed drifts by ~10 % over a minute, which one floor then one build
        # turned into the ratio; the median of paired rounds does not follow it.
        rounds = [(floor_rate(raw, args.samples, size), build_rate(raw, out, args.samples, size, 1))
                  for _ in range(args.rounds)]
        two = build_rate(raw, out, args.samples, size, 2)[0]
        floor, floor_cpu = (float(np.median([r[0][i] for r in rounds])) for i in (0, 1))
        one, one_cpu = (float(np.median([r[1][i] for r in rounds])) for i in (0, 1))
        ratio = float(np.median([b[0] / f[0] for f, b in rounds]))
        ratio_cpu = float(np.median([b[1] / f[1] for f, b in rounds]))
        # The build's own split needs no second measurement: the floor's work (decode, remap, encode) timed inside
        # the build, over the build's wall time, in the same seconds whatever the machine's drift.
        split = {k: float(np.median([b[2][k] for _, b in rounds])) for k in rounds[0][1][2]}
        inside = (split["decode"] + split["remap"] + split["encode"]) / sum(split.values())
        shards = BuildConfig(KITTI_02, "02", "kitti", tuple(list_images(str(raw))), args.samples, size).shard_count
        print(f"output {size[0]}x{size[1]}, {args.samples} samples in {shards} shards (default size), "
              f"{os.cpu_count()} cores, median of {args.rounds} alternating rounds")
        print(f"floor (remap + PNG encode) {floor:7.1f} samples/s")
        print(f"build --jobs 1             {one:7.1f} samples/s; the floor's work (decode, remap, encode) is "
              f"{inside:.3f} of its time (target >= 0.9; from the build's own stage timings, which drift cannot move)")
        paired = " ".join(f"{b[0] / f[0]:.3f}" for f, b in rounds)
        print(f"  against the floor run apart {ratio:.2f} x (rounds {paired}); by CPU time {ratio_cpu:.2f} x the "
              f"floor's {floor_cpu:.1f}/s")
        print("  the rest, ms/sample: " + ", ".join(f"{k} {1000 * v / args.samples:.1f}" for k, v in split.items()
                                                   if k not in ("decode", "remap", "encode")))
        print(f"build --jobs 2             {two:7.1f} samples/s  ({two / one:.2f} x jobs 1; target >= 1.7)")
        quick, full = reachability_seconds(size)
        print(f"reachability check         {quick:7.3f} s          (before --out is touched; {full:.3f} s when it "
              f"has to search for the largest APPD)")
        if args.rss:
            print("worker RSS, 10,000 samples at 348x128, --jobs 2:")
            rss_profile(raw, out, 10_000)


if __name__ == "__main__":
    main()
