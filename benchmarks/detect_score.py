"""Score appdgen.detect against known miscalibrations (issue 32's goals): MAE / the mean predictor's MAE of APPD (and
bend), per frame and per sequence, false alarms under the true calibration, and frames per second.

Each case: a belief drawn by Sampler(true, labels=True) around the true calibration (the camera that took the
frames), its label the draw's APPD (% of the raw diagonal, exact), frames rectified with the belief by the Detector
of that belief. The mean predictor predicts each belief's library mean label. Per frame: --beliefs beliefs, each on
--per-belief frames; per sequence: --sequences beliefs, each on --sequence consecutive frames (windows spread over
the test frames). With --baseline-frames A:B the frames A..B−1 are read under the true calibration and saved as a
baseline (Detector.save_baseline); the cases then use only the other frames and read against that baseline.
False alarms: the true calibration on every window of --sequence frames: verdicts "miscalibrated", and readings
above the threshold. Speed: evidence + solve per frame (one process, one thread).

Run (from the repository root; models and evidence are cached under --cache):
    python benchmarks/detect_score.py --frames /tmp/det/unseen --tag unseen
    python benchmarks/detect_score.py --frames ../shared/data/real/euroc_micro_cam1/data \\
        --calib ../shared/data/real/euroc_micro_cam1/sensor.yaml --baseline-frames 0:45 --tag euroc
    python benchmarks/detect_score.py --frames ../shared/data/real/vamr_desk/frames \\
        --calib ../shared/data/real/vamr_desk/camera_opencv.yaml --baseline-frames 0:30 --tag desk
Writes detect_score_<tag>.json (per-case readings, labels and the solve's statistics) beside --out.

Measured 2026-12-03 (commit 14bd58c's library; 2 shared cores, load 5-10; MAE / the mean predictor's, APPD):
    unseen streets (synth --frames 60 --seed 202, KITTI 02 1392x512), --beliefs 20 --per-belief 3 --sequences 20:
        per frame 0.80 (bend 0.60, rho 0.60), per sequence of 10 0.57 (bend 0.53, rho 0.77); bias -0.08 / -0.10;
        true calibration: 6 windows, none flagged, mean reading 0.05 %
    EuRoC cam1, baseline frames 0:45, --beliefs 12 --sequences 10: per frame 0.84, per sequence 0.95; true
        calibration 5 windows, none flagged, mean 0.16 %
    desk, baseline frames 0:30, --beliefs 8 --sequences 6: per frame 0.46, per sequence 0.42; true calibration
        3 windows, none flagged, mean 0.07 % (without a baseline the desk reads 0.87 % under its own file)
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from appdgen.analysis.studies import spearman  # noqa: E402
from appdgen.calib.calibration import Calibration  # noqa: E402
from appdgen.calib.formats import load  # noqa: E402
from appdgen.detect import Detector, Evidence  # noqa: E402
from appdgen.detect.edges import EdgePoints  # noqa: E402
from appdgen.detect.model import belief_crop, model_key  # noqa: E402
from appdgen.detect.posterior import posterior  # noqa: E402
from appdgen.geometry.appd import px_to_pct  # noqa: E402
from appdgen.geometry.bend import split_warp  # noqa: E402
from appdgen.sampling.sampler import Sampler  # noqa: E402
from appdgen.sources.inputs import iter_images, resolve_inputs  # noqa: E402

cv2.setNumThreads(1)
FRAME_SEED = 9001  # per-frame beliefs: Sampler(true).draw(FRAME_SEED, j)
SEQUENCE_SEED = 9002  # per-sequence beliefs
THRESHOLD = 0.5


@dataclass
class Case:
    """One scored reading: label, prediction and what the solve saw."""

    kind: str
    frames: list[int]
    appd: float
    bend: float
    pred: float | None
    pred_sd: float | None
    pred_bend: float | None
    p_above: float | None
    segments: int
    model: str
    h: list
    g: list
    sweep: dict  # κ → posterior mean APPD (--kappas)


class Frames:
    """The raw frames and the evidence of (belief, frame) pairs, cached on disk as npz."""

    def __init__(self, spec: str, calib: str, cache: Path):
        inputs = resolve_inputs(spec, calib)
        self.true = inputs.reference
        self.raw = list(iter_images(list(inputs.images), channels=1))
        self.names = [im.name for im in inputs.images]
        self.cache = cache
        self.seconds: list[float] = []

    def evidence(self, det: Detector, i: int) -> Evidence:
        """Frame i's evidence under a detector's belief (cached)."""
        tag = hashlib.sha1(f"{self.names[i]} {det.edge_params}".encode()).hexdigest()[:16]
        path = self.cache / "evidence" / f"{model_key(det.belief, det.max_fov)}-{tag}.npz"
        if path.exists():
            with np.load(path) as z:
                pts = EdgePoints(**{k: z[k] for k in EdgePoints.__dataclass_fields__})
            return Evidence(self.names[i], pts.segments, pts)
        ev = det.evidence(self.raw[i], self.names[i])
        self.seconds.append(ev.seconds)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **{k: getattr(ev.points, k) for k in EdgePoints.__dataclass_fields__})
        return ev


def labels(true: Calibration, belief: Calibration, appd_px: float) -> tuple[float, float]:
    """APPD and bend (% of the raw diagonal) of a belief against the true camera (bend as a build labels it)."""
    if belief == true:
        return 0.0, 0.0
    bend = split_warp(true, belief_crop(true, None), belief, belief_crop(belief, None)).bend_px
    return px_to_pct(appd_px, true), px_to_pct(bend, true)


def score(cases: list[Case], mean_label: dict[str, float]) -> dict:
    """MAE / mean predictor's MAE (APPD, bend), Spearman ρ, abstentions."""
    done = [c for c in cases if c.pred is not None]
    if not done:
        return {"n": len(cases), "abstained": len(cases)}
    y = np.array([c.appd for c in done])
    p = np.array([c.pred for c in done])
    m = np.array([mean_label[c.model] for c in done])
    yb = np.array([c.bend for c in done])
    pb = np.array([c.pred_bend for c in done])
    return {"n": len(cases), "abstained": len(cases) - len(done), "mae": float(np.abs(p - y).mean()),
            "ratio": float(np.abs(p - y).mean() / np.abs(m - y).mean()), "rho": spearman(y, p),
            "bend_ratio": float(np.abs(pb - yb).mean() / np.abs(yb - yb.mean()).mean()),
            "bias": float((p - y).mean())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", required=True)
    ap.add_argument("--calib", default=None, help="[FRAMES/calibration.yaml]")
    ap.add_argument("--tag", default="unseen")
    ap.add_argument("--beliefs", type=int, default=30)
    ap.add_argument("--per-belief", type=int, default=3)
    ap.add_argument("--sequences", type=int, default=12)
    ap.add_argument("--sequence", type=int, default=10)
    ap.add_argument("--baseline-frames", default=None, help="A:B frames read under the true calibration")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/det/cache"))
    ap.add_argument("--out", type=Path, default=Path("."))
    ap.add_argument("--kappas", default="", help="also score the posterior at these tempering values (1,3,10)")
    args = ap.parse_args()
    kappas = [float(k) for k in args.kappas.split(",") if k]
    calib = args.calib or str(Path(args.frames) / "calibration.yaml")
    frames = Frames(args.frames, calib, args.cache)
    true, nf = frames.true, len(frames.raw)
    ref = Detector(true, cache_dir=args.cache)
    test = list(range(nf))
    baseline = None
    if args.baseline_frames:
        a, b = (int(x) for x in args.baseline_frames.split(":"))
        baseline = ref.save_baseline([frames.evidence(ref, i) for i in range(a, b)], f"frames {a}:{b}")
        test = [i for i in test if not a <= i < b]
    sampler = Sampler(true, labels=True)
    cases, mean_label = [], {}
    windows = [test[k:k + args.sequence] for k in range(0, len(test) - args.sequence + 1, args.sequence)]
    start = time.time()
    solve_seconds: list[float] = []

    def run(kind: str, belief: Calibration, appd_px: float, idx: list[int], det: Detector | None = None) -> None:
        det = det or Detector(belief, cache_dir=args.cache)
        key = model_key(belief, None)
        mean_label[key] = float(det.model.appd.mean())
        ev = [frames.evidence(det, i) for i in idx]
        t0 = time.perf_counter()
        r = det.read(ev, baseline=baseline)
        if len(idx) == 1:
            solve_seconds.append(time.perf_counter() - t0)
        est = det.estimate(ev, baseline)
        y, yb = labels(true, belief, appd_px)
        sweep = {f"{kp:g}": posterior(det.model, est.h, est.g, kp, THRESHOLD).appd for kp in kappas}
        cases.append(Case(kind, idx, y, yb, r.appd_pct, r.appd_sd_pct, r.bend_pct, r.p_above, r.segments, key,
                          est.h.tolist(), est.g.tolist(), sweep))

    for j in range(args.beliefs):
        d = sampler.draw(FRAME_SEED, j)
        det = Detector(d.calib, cache_dir=args.cache)
        for m in range(args.per_belief):
            run("frame", d.calib, d.appd_px, [test[(j * args.per_belief + m) * 7 % len(test)]], det)
        print(f"  belief {j + 1}/{args.beliefs} {time.time() - start:.0f} s", flush=True)
    for j in range(args.sequences):
        d = sampler.draw(SEQUENCE_SEED, j)
        run("sequence", d.calib, d.appd_px, windows[j % len(windows)])
    for w in windows:
        run("true", true, 0.0, w, ref)
    summary = {"frame": score([c for c in cases if c.kind == "frame"], mean_label),
               "sequence": score([c for c in cases if c.kind == "sequence"], mean_label)}
    truth = [c for c in cases if c.kind == "true"]
    summary["true_calibration"] = {
        "windows": len(truth), "flagged": sum(c.p_above is not None and c.p_above >= 0.95 for c in truth),
        "above_threshold": sum(c.pred is not None and c.pred > THRESHOLD for c in truth),
        "mean_appd": float(np.mean([c.pred for c in truth if c.pred is not None] or [np.nan]))}
    if frames.seconds and solve_seconds:
        summary["frames_per_second"] = float(1.0 / (np.median(frames.seconds) + np.median(solve_seconds)))
    for kp in (cases[0].sweep if cases else {}):
        for kind in ("frame", "sequence"):
            sub = [c for c in cases if c.kind == kind and c.pred is not None]
            if sub:
                y = np.array([c.appd for c in sub])
                p = np.array([c.sweep[kp] for c in sub])
                m = np.array([mean_label[c.model] for c in sub])
                summary.setdefault("kappa_sweep", {}).setdefault(kind, {})[kp] = round(float(
                    np.abs(p - y).mean() / np.abs(m - y).mean()), 3)
    print(json.dumps(summary, indent=1))
    out = args.out / f"detect_score_{args.tag}.json"
    out.write_text(json.dumps({"summary": summary, "args": {k: str(v) for k, v in vars(args).items()},
                               "cases": [c.__dict__ for c in cases]}) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
