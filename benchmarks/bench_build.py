"""Build throughput against its floor, the PNG encoders and decoders, and --jobs 2 scaling, measured in one run
(issues #4 item 8, #13 items 1, 6 and 9, #25).

encoders = for each --encoder installed (dataset/encoders.py): ms/sample at 348x128 and 1392x512 over remapped
          street frames, bytes/sample, decode ms/sample with OpenCV and pyspng, the bytes read back bit-identical;
floor   = LANCZOS4 remap + the encoder's PNG of the same raw images at the same output size (what any generator
          pays); today's floor is remap + OpenCV's PNG level 1;
jobs 1  = `build --jobs 1 --encoder E` samples/s, default shard size: against its own floor (target >= 0.9) and
          today's (target >= 1.3 with the default); the in-build share = the floor's work (decode, remap, encode, from
          the build's own stage timings) over the build's wall time (target >= 0.9);
jobs 2  = `--jobs 2` against `--jobs 1` (target >= 1.8), with the workers' CPU seconds per sample (build.json
          timings.cpu_seconds) and the parent's, so the loss splits into more CPU per sample (memory bandwidth,
          a shared core) and idle workers (the parent's work, scheduling);
check   = the reachability check a build runs before touching --out (KITTI camera 02, paper's ranges);
--rss   = peak RSS per worker over a 10,000-sample build at 348x128, and whether it grows.
Builds, floors and codecs alternate over --rounds and medians are printed (this machine's speed drifts by ~10 %
over a minute, and other work on it moves one measurement, not a round's ratios). Everything runs warm (a 4-sample
build first pays the one-time imports). Raw frames: `appdgen synth` street frames at full size.
Run: make bench   (or: python benchmarks/bench_build.py [--samples 120] [--size 1392x512] [--rounds 3] [--rss])
     python benchmarks/bench_build.py --filters   (libdeflate's row filters and levels: why Sub at level 1)
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

from appdgen.calib.calibration import Calibration
from appdgen.calib.formats import load
from appdgen.dataset.build import build
from appdgen.dataset.encoders import DEFAULT_ENCODER, ENCODERS, LEGACY_ENCODER, LIBDEFLATE_LEVEL, sub_filtered_rows
from appdgen.dataset.plan import BuildConfig
from appdgen.geometry.maps import rectify
from appdgen.sampling.sampler import Sampler
from appdgen.sources.files import list_images

try:
    import pyspng
except ImportError:
    pyspng = None

SIZES = ((348, 128), (1392, 512))


def make_raw(folder: Path, count: int) -> Calibration:
    """Street frames of KITTI camera 02 at full size (appdgen synth); returns their calibration."""
    subprocess.run([sys.executable, "-m", "appdgen.cli", "synth", "--frames", str(count), "--out", str(folder),
                    "--jobs", "1", "--quiet"], check=True)
    return load(folder / "calibration.yaml")


def encoders_here() -> list[str]:
    """The --encoder choices installed here, today's (opencv, the ratios' reference) first."""
    return [LEGACY_ENCODER] + [n for n, e in ENCODERS.items() if n != LEGACY_ENCODER and e.available()]


def _ms(function, items: list) -> float:
    """Median milliseconds of function(item) over items."""
    times = []
    for item in items:
        start = time.perf_counter()
        function(item)
        times.append(time.perf_counter() - start)
    return 1000 * float(np.median(times))


def codec_round(samples: list[np.ndarray], name: str) -> dict:
    """One encoder over remapped samples: encode ms, bytes, decode ms (OpenCV, pyspng), exact round trip."""
    encoder = ENCODERS[name]
    data = [encoder.encode(s) for s in samples]
    exact = all(np.array_equal(cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_UNCHANGED), s)
                for d, s in zip(data, samples, strict=True)) and data == [encoder.encode(s) for s in samples]
    result = {"encode": _ms(encoder.encode, samples), "bytes": float(np.mean([len(d) for d in data])),
              "opencv": _ms(lambda d: cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_UNCHANGED), data),
              "exact": exact}
    if pyspng is not None:
        result["pyspng"] = _ms(pyspng.load, data)
        result["exact"] = exact and all(np.array_equal(pyspng.load(d)[:, :, ::-1], s)
                                        for d, s in zip(data, samples, strict=True))
    return result


def codec_table(raw_dir: Path, calib: Calibration, rounds: int) -> None:
    """Print each encoder's medians at both sizes, OpenCV's the reference of the ratios."""
    cv2.setNumThreads(1)
    raws = [cv2.imread(str(p)) for p in sorted(raw_dir.glob("*.png"))]
    print(f"encoders ({len(raws)} street frames remapped per size, median of {rounds} alternating rounds; decode "
          f"{'OpenCV / pyspng' if pyspng else 'OpenCV (pyspng not installed)'})")
    for size in SIZES:
        rect = rectify(calib, size)
        samples = [cv2.remap(r, rect.map_x, rect.map_y, cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REFLECT_101)
                   for r in raws] * (8 if size[0] < 1000 else 2)
        names = encoders_here()
        runs = [[codec_round(samples, n) for n in names] for _ in range(rounds)]
        base = float(np.median([r[0]["encode"] for r in runs]))
        for i, name in enumerate(names):
            med = {k: float(np.median([r[i][k] for r in runs])) for k in runs[0][i] if k != "exact"}
            spng = f" / {med['pyspng']:5.2f}" if "pyspng" in med else ""
            print(f"  {size[0]}x{size[1]} {name:10s} encode {med['encode']:6.2f} ms ({base / med['encode']:4.1f} x "
                  f"opencv)  {med['bytes'] / 1e3:7.1f} kB  decode {med['opencv']:5.2f}{spng} ms  "
                  f"read back bit-identical: {all(r[i]['exact'] for r in runs)}")


def filtered_rows(image: np.ndarray, kind: str) -> np.ndarray:
    """PNG scanlines of an 8-bit image with one filter on every row (None, Sub, Up or Average; RGB order):
    H×(W·channels + 1) uint8, as the libdeflate encoder would hand them to zlib."""
    if kind == "Sub":
        return sub_filtered_rows(image)
    channels = 1 if image.ndim == 2 else image.shape[2]
    rows = (cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if channels == 3 else image).reshape(image.shape[0], -1)
    above = np.vstack([np.zeros_like(rows[:1]), rows[:-1]])
    if kind == "None":
        body = rows
    elif kind == "Up":
        body = rows - above  # uint8: wraps modulo 256, as PNG's filters do
    else:  # Average: x − floor((left + up) / 2)
        left = np.hstack([np.zeros_like(rows[:, :channels]), rows[:, :-channels]])
        body = rows - ((left.astype(np.uint16) + above) // 2).astype(np.uint8)
    code = {"None": 0, "Up": 2, "Average": 3}[kind]
    return np.hstack([np.full((rows.shape[0], 1), code, np.uint8), body])


def filter_table(raw_dir: Path, calib: Calibration, rounds: int) -> None:
    """libdeflate's zlib stream over each PNG row filter and level, both sizes: how LIBDEFLATE_LEVEL and the Sub
    filter were chosen (compression ms/sample, filtering included, and kB/sample; medians over rounds)."""
    import deflate

    cv2.setNumThreads(1)
    raws = [cv2.imread(str(p)) for p in sorted(raw_dir.glob("*.png"))]
    print(f"libdeflate filters and levels ({len(raws)} street frames remapped per size, median of {rounds} "
          f"rounds; the encoder writes Sub at level {LIBDEFLATE_LEVEL})")
    choices = [("Sub", 1), ("Sub", 2), ("Sub", 3), ("None", 1), ("Up", 1), ("Average", 1)]
    for size in SIZES:
        rect = rectify(calib, size)
        samples = [cv2.remap(r, rect.map_x, rect.map_y, cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REFLECT_101)
                   for r in raws]
        # The stream's length is fixed by the pixels and the choice: measured once, the time every round.
        kb = [np.mean([len(deflate.zlib_compress(filtered_rows(s, kind), level)) for s in samples]) / 1e3
              for kind, level in choices]
        runs = [[_ms(lambda s: deflate.zlib_compress(filtered_rows(s, kind), level), samples)
                 for kind, level in choices] for _ in range(rounds)]
        for i, (kind, level) in enumerate(choices):
            ms = float(np.median([r[i] for r in runs]))
            print(f"  {size[0]}x{size[1]} {kind:7s} level {level}  {ms:6.2f} ms  {kb[i]:7.1f} kB")


def floor_rate(raw_dir: Path, calib: Calibration, samples: int, size: tuple[int, int], encoder: str) -> float:
    """Samples/s of remap + encode alone (reference maps, one decode per image as the build does)."""
    cv2.setNumThreads(1)
    rect, encode = rectify(calib, size), ENCODERS[encoder].encode
    images = sorted(raw_dir.glob("*.png"))
    start = time.perf_counter()
    for index in range(samples):
        if index % (samples // len(images)) == 0:
            raw = cv2.imread(str(images[index * len(images) // samples]))
        encode(cv2.remap(raw, rect.map_x, rect.map_y, cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REFLECT_101))
    return samples / (time.perf_counter() - start)


def build_rate(raw_dir: Path, calib: Calibration, out: Path, samples: int, size: tuple[int, int], jobs: int,
               encoder: str = DEFAULT_ENCODER) -> dict:
    """A whole build with the default shard size (config and reachability check included): samples/s, the
    floor's share of its wall time (stage timings), ms/sample of the rest, and CPU seconds per sample of the
    workers and of this (the parent) process."""
    shutil.rmtree(out, ignore_errors=True)  # into a fresh --out: deleting the last run's shards is not building
    start, cpu = time.perf_counter(), time.process_time()
    config = BuildConfig(calib, "02", "kitti", tuple(list_images(str(raw_dir))), samples, size, encoder=encoder)
    timings = build(config, out, jobs=jobs, overwrite=True, progress=False)["timings"]
    wall, parent = time.perf_counter() - start, time.process_time() - cpu
    stages = timings["stage_seconds"]
    worker_cpu = timings["cpu_seconds"]
    return {"rate": samples / wall, "inside": (stages["decode"] + stages["remap"] + stages["encode"]) / wall,
            "rest": {**{k: v for k, v in stages.items() if k not in ("decode", "remap", "encode")},
                     "other": wall - sum(stages.values())},
            "cpu": worker_cpu / samples, "parent": (parent - (worker_cpu if jobs == 1 else 0)) / samples,
            "in_shards": sum(stages.values()) / wall}


def reachability_seconds(calib: Calibration, size: tuple[int, int]) -> tuple[float, float]:
    """Seconds of the reachability check a build runs before --out is touched, and of the full search for the
    largest APPD it runs when no quick ray reaches --appd-max (best of 3 each, sampler set-up included)."""
    quick = full = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        Sampler(calib, size=size).check_reachable()
        quick = min(quick, time.perf_counter() - start)
        start = time.perf_counter()
        Sampler(calib, size=size).reach()
        full = min(full, time.perf_counter() - start)
    return quick, full


def rss_profile(raw_dir: Path, out: Path, samples: int) -> None:
    """Peak and progression of worker RSS over a --jobs 2 build at 348x128, polled from /proc."""
    cmd = [sys.executable, "-m", "appdgen.cli", "build", "--calib", str(raw_dir / "calibration.yaml"), "--images",
           str(raw_dir), "--out", str(out), "--samples", str(samples), "--size", "348x128", "--jobs", "2",
           "--shard-size", "500", "--overwrite", "--quiet"]
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
                        help="codecs, floors and builds measured alternately this many times; medians are printed")
    parser.add_argument("--rss", action="store_true", help="also profile worker RSS over 10,000 samples")
    parser.add_argument("--rss-only", action="store_true", help="only profile worker RSS")
    parser.add_argument("--filters", action="store_true",
                        help="only compare libdeflate's PNG row filters and levels (how the encoder's were chosen)")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    print(f"load average at start: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} "
          f"on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        raw, out = Path(tmp) / "raw", Path(tmp) / "out"
        calib = make_raw(raw, 8)
        if args.rss_only:
            rss_profile(raw, out, 10_000)
            return
        if args.filters:
            filter_table(raw, calib, args.rounds)
            return
        codec_table(raw, calib, args.rounds)
        build_rate(raw, calib, out, 4, size, 1)  # warm-up: one-time imports
        names = encoders_here()
        # Alternating rounds: each round measures every floor and build once, so drift moves all of a round alike.
        rounds = [{name: (floor_rate(raw, calib, args.samples, size, name),
                          build_rate(raw, calib, out, args.samples, size, 1, name)) for name in names}
                  for _ in range(args.rounds)]
        shards = BuildConfig(calib, "02", "kitti", tuple(list_images(str(raw))), args.samples, size).shard_count
        print(f"build {size[0]}x{size[1]}, {args.samples} samples in {shards} shards (default size), median of "
              f"{args.rounds} alternating rounds")
        today = float(np.median([r[LEGACY_ENCODER][0] for r in rounds]))
        print(f"  today's floor (remap + opencv PNG) {today:7.1f} samples/s")
        for name in names:
            floor = float(np.median([r[name][0] for r in rounds]))
            one = float(np.median([r[name][1]["rate"] for r in rounds]))
            own = float(np.median([r[name][1]["rate"] / r[name][0] for r in rounds]))
            vs_today = float(np.median([r[name][1]["rate"] / r[LEGACY_ENCODER][0] for r in rounds]))
            inside = float(np.median([r[name][1]["inside"] for r in rounds]))
            rest = {k: 1000 * float(np.median([r[name][1]["rest"][k] for r in rounds])) / args.samples
                    for k in rounds[0][name][1]["rest"]}
            label = f"{name} (the default)" if name == DEFAULT_ENCODER else name
            print(f"  --encoder {label}: floor {floor:6.1f}/s, build --jobs 1 {one:6.1f}/s: {own:.2f} x its floor, "
                  f"{vs_today:.2f} x today's; in-build share {inside:.3f}")
            print("      the rest, ms/sample: " + ", ".join(f"{k} {v:.1f}" for k, v in rest.items()))
        jobs_table(raw, calib, out, args.samples, size, args.rounds)
        quick, full = reachability_seconds(calib, size)
        print(f"reachability check {quick:7.3f} s (before --out is touched; {full:.3f} s when it has to search for "
              f"the largest APPD)")
        if args.rss:
            print("worker RSS, 10,000 samples at 348x128, --jobs 2:")
            rss_profile(raw, out, 10_000)
    print(f"load average at end: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")


def jobs_table(raw: Path, calib: Calibration, out: Path, samples: int, size: tuple[int, int], rounds: int) -> None:
    """--jobs 2 against --jobs 1 (default encoder and shard size), alternating, with CPU seconds per sample; the
    first --jobs 2 build of this process, which starts the workers, separately (a command pays it every time)."""
    cold = build_rate(raw, calib, out, samples, size, 2)
    runs = [(build_rate(raw, calib, out, samples, size, 1), build_rate(raw, calib, out, samples, size, 2))
            for _ in range(rounds)]
    speedup = float(np.median([two["rate"] / one["rate"] for one, two in runs]))
    med = {j: {k: float(np.median([r[j][k] for r in runs])) for k in ("rate", "cpu", "parent", "in_shards")}
           for j in (0, 1)}
    # Perfect scaling is 2 x; what is lost splits into more CPU per sample in each worker (two busy cores share
    # memory bandwidth and caches) and worker time spent not computing: outside a shard (the workers' start, the
    # parent's check, plan and index, imbalance) or inside one but off the CPU (fsync, other load on the machine).
    cpu_growth = med[1]["cpu"] / med[0]["cpu"]
    busy = med[1]["cpu"] * med[1]["rate"] / 2
    print(f"--jobs 2 {med[1]['rate']:6.1f}/s vs --jobs 1 {med[0]['rate']:6.1f}/s: {speedup:.2f} x (target >= 1.8); "
          f"worker CPU {1000 * med[0]['cpu']:.1f} -> {1000 * med[1]['cpu']:.1f} ms/sample ({cpu_growth:.2f} x), "
          f"workers busy {busy:.2f} of the wall time (inside a shard {med[1]['in_shards'] / 2:.2f}: the rest is their "
          f"start and the parent's set-up and index), parent {1000 * med[1]['parent']:.1f} ms CPU/sample")
    start = samples / cold["rate"] - samples / med[1]["rate"]
    print(f"  with the workers' start (a process's first --jobs 2 build, as every command's): {cold['rate']:6.1f}/s, "
          f"{cold['rate'] / med[0]['rate']:.2f} x --jobs 1; starting them cost {start:.2f} s")


if __name__ == "__main__":
    main()
