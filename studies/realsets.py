"""appdgen detect on the real frames in ../shared/data/real: the desk and EuRoC camera 1, each under its true file
and under beliefs drawn around it (Sampler(truth).draw(SEED, i): what `appdgen build` makes), read per window with
and without a baseline from the first frames, scored against the truth.

    python -m studies.realsets [--sets desk,euroc] [--beliefs 16] [--out runs/realsets]

Per set and baseline: MAE of the windows' APPD readings / the mean predictor's (the mean label of the prior's
draws), the truth inside 2 sd (coverage, over every belief's windows), true-file windows flagged, beliefs above
0.5 % flagged (windows), the median sd, the windows whose sd lies below their belief's window-to-window sd of
readings (sd_below_spread; sd_over_spread the median ratio), and frames/s; the same per frame (every
single_stride-th test frame read alone: "per_frame", its "windows" the frames read); and the frames to flag a 1 %
miscalibration: every belief of APPD NEAR_ONE (and the true file) read on the first n test frames pooled, n
doubling from the window up to all of them, the least n read `miscalibrated` (none: not within the test frames).
Evidence is cached per belief under OUT/cache (delete it after a change to appdgen/detect/edges.py). Uses the
product's public API (Detector.evidence, save_baseline, read) and the mean predictor's draws of train.scoring.
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

import appdgen
from appdgen.detect import DEFAULT_THRESHOLD_PCT, Detector
from appdgen.sampling.sampler import Sampler
from train.scoring import prior_draws

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
SEED = 77  # the beliefs' draws
NEAR_ONE = (0.8, 1.25)  # APPD, %: the beliefs that stand for "a 1 % miscalibration"


@dataclass(frozen=True)
class RealSet:
    """A real sequence: its calibration, its frames (sorted), the baseline's frames and the windows after them."""

    calib: Path
    frames: Path
    pattern: str
    baseline: tuple[int, int]  # [first, last) frame indices of the baseline
    test: tuple[int, int]  # [first, last) frame indices read in windows
    window: int


SETS = {"desk": RealSet(SHARED / "vamr_desk" / "camera_opencv.yaml", SHARED / "vamr_desk" / "frames", "*.jpg",
                        (0, 100), (100, 300), 50),
        "euroc": RealSet(SHARED / "euroc_micro_cam1" / "sensor.yaml", SHARED / "euroc_micro_cam1" / "data", "*.png",
                         (0, 35), (35, 95), 10)}


def beliefs(truth, count: int) -> list[tuple[object, float]]:
    """The true file (APPD 0) and `count` non-reference sampler draws around it with their APPD (%)."""
    sampler = Sampler(truth)
    out, i = [(truth, 0.0)], 0
    while len(out) < count + 1:
        d = sampler.draw(SEED, i)
        i += 1
        if not d.is_reference:
            out.append((d.calib, appdgen.appd(truth, d.calib)[1]))
    return out


def mean_label(truth) -> float:
    """The mean predictor: the mean APPD (%) of the prior's draws (train.scoring.prior_draws)."""
    return float(np.mean([appdgen.appd(truth, d.calib)[1] for d in prior_draws(Sampler(truth))]))


def cached(path: Path, make):
    """make()'s value, pickled at path."""
    if path.exists():
        return pickle.loads(path.read_bytes())
    value = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(value))
    return value


def read_set(name: str, s: RealSet, count: int, out: Path, log) -> dict:
    """Every belief's windows read with and without the baseline, and the scores."""
    truth = appdgen.load(str(s.calib))
    raws = raw_frames(s, 0, None)
    ref = Detector(truth)
    base_ev = cached(out / "cache" / f"{name}-base.pkl",
                     lambda: [ref.evidence(r) for r in raws[s.baseline[0]:s.baseline[1]]])
    start = time.perf_counter()
    baseline = ref.save_baseline(base_ev, f"{name} frames {s.baseline[0]}-{s.baseline[1] - 1}")
    save_seconds = time.perf_counter() - start
    camera_map = None if baseline.camera_map is None else baseline.camera_map.to_dict()
    log(f"{name} baseline: {save_seconds:.1f} s, camera map {camera_map}")
    mean = cached(out / "cache" / f"{name}-mean.pkl", lambda: mean_label(truth))
    rows, grown, singles = [], [], []
    for k, (belief, appd) in enumerate(beliefs(truth, count)):
        det = Detector(belief)
        ev = cached(out / "cache" / f"{name}-{k}.pkl",
                    lambda det=det: [det.evidence(r) for r in raws[s.test[0]:s.test[1]]])
        for start in range(0, len(ev) - s.window + 1, s.window):
            for bl in (None, baseline):
                rows.append(reading_row(k, appd, bl is not None, s.test[0] + start,
                                        det.read(ev[start:start + s.window], bl)))
        for i in range(0, len(ev), single_stride(s.window)):
            for bl in (None, baseline):
                singles.append(reading_row(k, appd, bl is not None, s.test[0] + i, det.read(ev[i:i + 1], bl)))
        if k == 0 or NEAR_ONE[0] <= appd <= NEAR_ONE[1]:
            grown.extend(grow(det, ev, baseline, s.window, k, appd))
        log(f"{name} belief {k} (APPD {appd:.2f} %): " + " ".join(
            f"{x['appd']:.2f}±{x['sd']:.2f}{'*' if x['verdict'] == 'miscalibrated' else ''}"
            if x["appd"] is not None else "abstain" for x in rows if x["belief"] == k))
    return {"set": name, "mean": mean, "rows": rows, "grown": grown, "singles": singles,
            "save_baseline_seconds": save_seconds, "camera_map": camera_map}


def raw_frames(s: RealSet, first: int, count: int | None) -> list[np.ndarray]:
    """Grey raw frames first … first + count − 1 of a real set, sorted by name (count None: all from first)."""
    files = sorted(s.frames.glob(s.pattern))[first:None if count is None else first + count]
    return [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]


def reading_row(belief: int, truth: float, baseline: bool, first: int, r) -> dict:
    """One window's (or frame's) reading as the scores take it, with its reading before the camera map."""
    return {"belief": belief, "truth": truth, "baseline": baseline, "first": first, "appd": r.appd_pct,
            "sd": r.appd_sd_pct, "verdict": r.verdict, "reason": r.reason, "raw": r.raw_appd_pct,
            "raw_sd": r.raw_appd_sd_pct}


def single_stride(window: int) -> int:
    """Every this many test frames one is also read alone (per frame scores): about ten per window."""
    return max(1, window // 10)


def pool_sizes(window: int, frames: int) -> list[int]:
    """Frames pooled: the window, doubling, and all of them (each at most frames)."""
    sizes = []
    n = window
    while n < frames:
        sizes.append(n)
        n *= 2
    return sizes + [frames]


def grow(det: Detector, ev: list, baseline, window: int, belief: int, appd: float) -> list[dict]:
    """The first n frames of ev read pooled, with and without the baseline, for every n of pool_sizes."""
    return [{"belief": belief, "truth": appd, "baseline": bl is not None, "frames": n, "appd": r.appd_pct,
             "sd": r.appd_sd_pct, "verdict": r.verdict}
            for n in pool_sizes(window, len(ev)) for bl in (None, baseline) for r in [det.read(ev[:n], bl)]]


def frames_to_flag(result: dict, with_baseline: bool) -> dict:
    """Per belief of grow's rows (keyed by its index and APPD): the least frames pooled that read `miscalibrated`
    (None: never), and its readings."""
    out = {}
    for r in result.get("grown", []):
        if r["baseline"] != with_baseline:
            continue
        entry = out.setdefault(f"belief {r['belief']} ({r['truth']:.2f} %)", {"flagged_at": None, "reads": []})
        entry["reads"].append(f"{r['frames']}: {r['appd']:.2f}±{r['sd']:.2f}" if r["appd"] is not None else
                              f"{r['frames']}: abstain")
        if r["verdict"] == "miscalibrated" and entry["flagged_at"] is None:
            entry["flagged_at"] = r["frames"]
    return out


def scores(result: dict, with_baseline: bool) -> dict:
    """MAE / the mean predictor, coverage, flags under the truth and above the threshold, median sd, and the
    windows whose sd is below their belief's window-to-window sd of readings (and the median ratio of the two)."""
    rows = [r for r in result["rows"] if r["baseline"] == with_baseline and r["appd"] is not None]
    truth = np.array([r["truth"] for r in rows])
    read = np.array([r["appd"] for r in rows])
    sd = np.array([r["sd"] for r in rows])
    flag = np.array([r["verdict"] == "miscalibrated" for r in rows])
    true_file = truth == 0
    above = truth > DEFAULT_THRESHOLD_PCT
    belief = np.array([r["belief"] for r in rows])
    scatter = {k: read[belief == k].std(ddof=1) if (belief == k).sum() > 1 else np.nan for k in set(belief.tolist())}
    spread = np.array([scatter[k] for k in belief.tolist()])
    return {"set": result["set"], "baseline": with_baseline, "windows": len(rows),
            "mae_vs_mean": float(np.abs(read - truth).mean() / np.abs(result["mean"] - truth).mean()),
            "coverage": float((np.abs(read - truth) <= 2 * sd).mean()),
            "true_flagged": f"{int(flag[true_file].sum())}/{int(true_file.sum())}",
            "above_flagged": f"{int(flag[above].sum())}/{int(above.sum())}",
            "median_sd": float(np.median(sd)),
            "sd_below_spread": f"{int((sd < spread).sum())}/{int(np.isfinite(spread).sum())}",
            "sd_over_spread": float(np.nanmedian(sd / spread)),
            "true_reads": [round(float(x), 2) for x in read[true_file]]}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", default="desk,euroc")
    ap.add_argument("--beliefs", type=int, default=16)
    ap.add_argument("--out", default="runs/realsets")
    a = ap.parse_args(argv)
    out = Path(a.out)
    found = []
    for name in a.sets.split(","):
        result = read_set(name, SETS[name], a.beliefs, out, lambda line: print(line, file=sys.stderr, flush=True))
        found.append(result)
        for bl in (False, True):
            per_frame = scores(result | {"rows": result["singles"]}, bl)
            print(json.dumps(scores(result, bl) | {"frames_to_flag": frames_to_flag(result, bl), "per_frame": {
                k: per_frame[k] for k in ("windows", "mae_vs_mean", "coverage", "true_flagged", "above_flagged",
                                          "median_sd")}}), flush=True)
    (out / "readings.json").write_text(json.dumps(found) + "\n")


if __name__ == "__main__":
    main()
