"""appdgen synth's speed: frames/s for 1 and N jobs at full and quarter size, and CPU seconds per frame.

    python benchmarks/bench_synth.py [--frames-full 48] [--frames-quarter 192] [--jobs 2] [--trials 3]
                                     [--calib FILE --camera NAME]

The camera is the bundled KITTI 02 unless --calib names another (a fisheye renders through a cube of canvases).

Jobs 1 and N alternate trial by trial and the best of each is kept, so a machine shared with other work
biases neither side. Each task also reports the CPU seconds it used: CPU s/frame at N jobs against 1 job is
the parallel overhead, and CPU seconds over wall seconds the cores the run actually got, so the speed-up on
idle cores can be told apart from other work's load. Also checks that both job counts wrote the same bytes.
"""
from __future__ import annotations

import argparse
import functools
import shutil
import tempfile
import time
from pathlib import Path

from appdgen.calib.calibration import Calibration
from appdgen.calib.defaults import DEFAULT_CALIB_PATH
from appdgen.calib.formats import load
from appdgen.synth import CAR, frame_chunks, write_frames
from appdgen.util.distribute import run_unordered


def _timed_chunk(indices: range, **kw) -> tuple[int, float]:
    """synthesize's task, also returning the CPU seconds it took in its process."""
    start = time.process_time()
    return write_frames(indices, **kw), time.process_time() - start


def timed(calib: Calibration, frames: int, scale: float, jobs: int, out: Path) -> tuple[float, float]:
    """(wall seconds, CPU seconds of all tasks) of synthesize's work into a fresh folder."""
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    work = functools.partial(_timed_chunk, calib=calib, out=out, seed=5, scale=scale, mount=CAR)
    wall = time.perf_counter()
    cpu = sum(c for _, c in run_unordered(work, frame_chunks(frames, jobs), jobs))
    return time.perf_counter() - wall, cpu


def main() -> None:
    """Print one line per size: frames/s per job count, their ratio, CPU s/frame, identical bytes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames-full", type=int, default=48)
    ap.add_argument("--frames-quarter", type=int, default=192)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--calib", default=str(DEFAULT_CALIB_PATH))
    ap.add_argument("--camera", default=None, help="camera in --calib [default: 02 for the bundled file]")
    args = ap.parse_args()
    calib = load(args.calib, args.camera or ("02" if args.calib == str(DEFAULT_CALIB_PATH) else None))
    print(f"{args.calib} ({calib.model}, {calib.width}x{calib.height})")
    with tempfile.TemporaryDirectory() as tmp:
        for scale, frames in ((1.0, args.frames_full), (0.25, args.frames_quarter)):
            best: dict[int, tuple[float, float]] = {}
            for _ in range(args.trials):
                for jobs in (1, args.jobs):
                    wall, cpu = timed(calib, frames, scale, jobs, Path(tmp) / f"j{jobs}")
                    if jobs not in best or wall < best[jobs][0]:
                        best[jobs] = (wall, cpu)
            same = all((Path(tmp) / "j1" / p.name).read_bytes() == p.read_bytes()
                       for p in sorted((Path(tmp) / f"j{args.jobs}").glob("*.png")))
            (w1, c1), (wn, cn) = best[1], best[args.jobs]
            print(f"scale {scale:g}: {frames} frames, jobs 1 {frames / w1:.2f} frames/s, jobs {args.jobs} "
                  f"{frames / wn:.2f} frames/s ({w1 / wn:.2f}x); CPU s/frame {c1 / frames:.3f} at jobs 1, "
                  f"{cn / frames:.3f} at jobs {args.jobs} (overhead {cn / c1:.2f}x); cores got {c1 / w1:.2f} and "
                  f"{cn / wn:.2f}; identical files: {same}", flush=True)


if __name__ == "__main__":
    main()
