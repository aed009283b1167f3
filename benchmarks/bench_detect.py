"""What `appdgen detect` costs on one core: evidence + solve frames/s at KITTI's 1392x512, and a new belief's model.

    python benchmarks/bench_detect.py [--frames 20] [--sequence 10] [--images SPEC --calib FILE [--camera C]]

Renders --frames synthetic streets of the bundled KITTI camera 02 at its full raw size in memory (or reads
--images with --calib, as `appdgen detect` does), then times on one thread (OpenCV, BLAS and OpenMP pinned to 1):
the belief's model built uncached (a fresh cache folder) and loaded from that cache; per frame the evidence
(rectification and line evidence) and the frame's own solve, as `appdgen detect` does for every frame; and the
pooled solve of each --sequence. Prints frames/s (evidence + one solve a frame, decoding and rendering excluded),
the median milliseconds of each part, the model seconds, and the machine (CPU, load average) they were measured on.
"""
from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"  # one core: set before numpy loads its BLAS

import argparse  # noqa: E402
import platform  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from appdgen.calib.calibration import Calibration  # noqa: E402
from appdgen.calib.defaults import default_calibration  # noqa: E402
from appdgen.detect import Detector  # noqa: E402


def machine() -> str:
    """The CPU model, its core count and the 1-minute load average: what the figures were measured on."""
    model = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
                 if line.startswith("model name")]
        model = names[0] if names else model
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{model}, {os.cpu_count()} cores, load {load:.2f}"


def synthetic_frames(calib: Calibration, count: int, seed: int) -> Iterator[np.ndarray]:
    """`count` street frames of the camera at its raw size, grey as `appdgen detect` decodes them."""
    from appdgen.synth import frame_rng, render_frame

    for index in range(count):
        yield cv2.cvtColor(render_frame(calib, frame_rng(seed, index)), cv2.COLOR_BGR2GRAY)


def listed_frames(spec: str, calib_path: str, camera: str | None, count: int) -> tuple[Calibration, Iterator]:
    """The belief and the first `count` frames of an --images spec, as `appdgen detect` reads them."""
    from itertools import islice

    from appdgen.sources.inputs import iter_images, resolve_inputs

    inputs = resolve_inputs(spec, calib_path, camera, check_grey=False)
    return inputs.reference, islice(iter_images(list(inputs.images), channels=1), count)


CPU = [0.0]  # process CPU seconds spent inside timed() (one thread: the work itself, whatever the load)


def timed(call):
    """(call's result, its wall seconds); its CPU seconds are added to CPU."""
    start, cpu = time.perf_counter(), time.process_time()
    result = call()
    CPU[0] += time.process_time() - cpu
    return result, time.perf_counter() - start


def model_seconds(belief: Calibration, cache: Path) -> tuple[Detector, float, float]:
    """The detector, the model's seconds uncached (an empty cache folder) and loaded from that cache."""
    _, fresh = timed(lambda: Detector(belief, cache_dir=cache))
    detector, cached = timed(lambda: Detector(belief, cache_dir=cache))
    return detector, fresh, cached


def main() -> None:
    """Print the speed figures and the machine they were measured on."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="frames timed (default 20)")
    parser.add_argument("--sequence", type=int, default=10, help="frames pooled per sequence solve (default 10)")
    parser.add_argument("--seed", type=int, default=7, help="synthetic streets' seed")
    parser.add_argument("--images", default=None, help="read these frames instead (needs --calib)")
    parser.add_argument("--calib", default=None, help="the belief for --images")
    parser.add_argument("--camera", default=None, help="camera in --calib")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    if args.images:
        belief, frames = listed_frames(args.images, args.calib, args.camera, args.frames)
    else:
        belief = default_calibration("02")
        frames = synthetic_frames(belief, args.frames, args.seed)
    with tempfile.TemporaryDirectory() as cache:
        detector, fresh, cached = model_seconds(belief, Path(cache))
    evidence, spent, solves = [], [], []
    CPU[0] = 0.0
    for index, raw in enumerate(frames):
        one, seconds = timed(lambda: detector.evidence(raw, f"frame {index}"))
        _, solve = timed(lambda: detector.read([one]))
        evidence.append(one)
        spent.append(seconds)
        solves.append(solve)
    loop_cpu = CPU[0]
    pooled = [timed(lambda: detector.read(evidence[i:i + args.sequence]))[1]
              for i in range(0, len(evidence), args.sequence)]
    per_frame = np.add(spent, solves)
    width, height = belief.size
    print(f"appdgen detect, one core, {width}x{height} {belief.model}, {len(per_frame)} frames: "
          f"{len(per_frame) / per_frame.sum():.1f} frames/s (evidence + solve; "
          f"{len(per_frame) / loop_cpu:.1f} per CPU second)")
    print(f"  median ms a frame: evidence {1e3 * np.median(spent):.0f}, solve {1e3 * np.median(solves):.0f}; "
          f"a sequence of {args.sequence} pooled: {1e3 * np.median(pooled):.0f} ms; "
          f"segments a frame: median {np.median([e.segments for e in evidence]):.0f}")
    print(f"  model: {fresh:.1f} s uncached, {cached:.2f} s from the cache")
    print(f"  machine: {machine()}")


if __name__ == "__main__":
    main()
