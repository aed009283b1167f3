"""appdgen synth's speed: frames/s for 1 and N jobs at full and quarter KITTI size, and CPU seconds per frame.

    python benchmarks/bench_synth.py [--frames-full 48] [--frames-quarter 192] [--jobs 2] [--trials 3]

Jobs 1 and N alternate trial by trial and the best of each is kept, so a machine shared with other work
biases neither side; CPU seconds per frame (this process and its workers) size runs on other core counts.
Also checks that both job counts wrote the same bytes.
"""
from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

from appdgen.defaults import DEFAULT_CALIB_PATH
from appdgen.formats import load
from appdgen.synth import synthesize


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and its finished children."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def timed(frames: int, scale: float, jobs: int, out: Path) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one synthesize call into a fresh folder."""
    shutil.rmtree(out, ignore_errors=True)
    calib = load(DEFAULT_CALIB_PATH, "02")
    cpu, wall = cpu_seconds(), time.perf_counter()
    synthesize(calib, frames, out, seed=5, scale=scale, jobs=jobs)
    return time.perf_counter() - wall, cpu_seconds() - cpu


def main() -> None:
    """Print one line per size: frames/s per job count, their ratio, CPU s/frame, identical bytes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames-full", type=int, default=48)
    ap.add_argument("--frames-quarter", type=int, default=192)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--trials", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for scale, frames in ((1.0, args.frames_full), (0.25, args.frames_quarter)):
            best: dict[int, tuple[float, float]] = {}
            for _ in range(args.trials):
                for jobs in (1, args.jobs):
                    wall, cpu = timed(frames, scale, jobs, Path(tmp) / f"j{jobs}")
                    if jobs not in best or wall < best[jobs][0]:
                        best[jobs] = (wall, cpu)
            same = all((Path(tmp) / "j1" / p.name).read_bytes() == p.read_bytes()
                       for p in sorted((Path(tmp) / f"j{args.jobs}").glob("*.png")))
            (w1, c1), (wn, _) = best[1], best[args.jobs]
            print(f"scale {scale:g}: {frames} frames, jobs 1 {frames / w1:.2f} frames/s, jobs {args.jobs} "
                  f"{frames / wn:.2f} frames/s ({w1 / wn:.2f}x), {c1 / frames:.3f} CPU s/frame at jobs 1, "
                  f"identical files: {same}", flush=True)


if __name__ == "__main__":
    main()
