"""Fit appdgen.detect's error model on simulation: how much the solve's Gaussian likelihood must be tempered (κ) for
its posterior on the field's coefficients to be calibrated, per frame and per sequence.

On TRAINING streets (`appdgen synth --frames 60 --seed 101 --out /tmp/det/train`; the scored streets are seed 202)
each case is a belief drawn around the true camera, frames rectified with it, and the TRUE field coefficients c*
(the true camera's field in the belief's basis, geometry.bend.output_rest). At tempering κ the posterior on c is
N(ĉκ, Σκ) with Σκ = (H/κ + P)⁻¹, ĉκ = Σκ g/κ (P: the library's prior precision). Calibrated means
E[(c* − ĉκ)ᵀ Σκ⁻¹ (c* − ĉκ)] = K; the κ that achieves it is found per kind (frame, sequence) by bisection and fitted
as κ = a · frames^b (two kinds: two points). Prints the constants for appdgen/detect/errormodel.py.

Run: python benchmarks/detect_error_model.py --frames /tmp/det/train [--beliefs 12 --per-belief 4 --sequences 8]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from detect_score import Frames  # noqa: E402

from appdgen.detect import Detector  # noqa: E402
from appdgen.detect.posterior import posterior  # noqa: E402
from appdgen.geometry.appd import appd  # noqa: E402
from appdgen.detect.model import belief_crop  # noqa: E402
from appdgen.geometry.bend import output_rest  # noqa: E402
from appdgen.sampling.sampler import Sampler  # noqa: E402

FIT_SEED = 7001  # beliefs of the fit: apart from the scorer's seeds
KAPPAS = (3.0, 10.0, 30.0, 100.0)  # also printed: MAE / the mean predictor's of the posterior mean APPD at each


def true_coefficients(det: Detector, true) -> np.ndarray:
    """The true camera's field in the belief's basis (zeros field → its coefficients)."""
    m = det.model
    if true == det.belief:
        field = np.zeros_like(m.mean)
    else:
        uu, vv = np.meshgrid(m.grid_u, m.grid_v)
        field = output_rest(true, belief_crop(true, None), det.belief, belief_crop(det.belief, None), uu, vv)
    return (field.ravel() - m.mean.ravel()) @ m.basis.reshape(len(m.basis), -1).T


def mahalanobis(h: np.ndarray, g: np.ndarray, prior: np.ndarray, c_true: np.ndarray, kappa: float) -> float:
    """(c* − ĉκ)ᵀ Σκ⁻¹ (c* − ĉκ) / K at tempering κ."""
    info = h / kappa + prior
    c = np.linalg.solve(info, g / kappa)
    d = c_true - c
    return float(d @ info @ d / len(g))


def calibrated_kappa(stats: list[tuple], lo: float = 0.1, hi: float = 1e4) -> float:
    """κ whose mean normalised Mahalanobis distance over the cases is 1 (bisection in log κ)."""
    def excess(k):
        return np.mean([mahalanobis(h, g, p, c, k) for h, g, p, c in stats]) - 1.0

    a, b = np.log(lo), np.log(hi)
    for _ in range(40):
        mid = 0.5 * (a + b)
        if excess(np.exp(mid)) > 0:
            a = mid
        else:
            b = mid
    return float(np.exp(0.5 * (a + b)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", required=True)
    ap.add_argument("--beliefs", type=int, default=12)
    ap.add_argument("--per-belief", type=int, default=4)
    ap.add_argument("--sequences", type=int, default=8)
    ap.add_argument("--sequence", type=int, default=10)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/det/cache"))
    args = ap.parse_args()
    frames = Frames(args.frames, str(Path(args.frames) / "calibration.yaml"), args.cache)
    true, nf = frames.true, len(frames.raw)
    sampler = Sampler(true)
    stats: dict[str, list] = {"frame": [], "sequence": []}
    reads: dict[str, list] = {"frame": [], "sequence": []}  # (label, {κ: posterior mean APPD}, library mean)
    for j in range(args.beliefs + args.sequences):
        kind = "frame" if j < args.beliefs else "sequence"
        belief = sampler.draw(FIT_SEED, j).calib
        det = Detector(belief, cache_dir=args.cache)  # the full library, whatever the load
        c_true = true_coefficients(det, true)
        prior = np.diag(1.0 / det.model.var)
        groups = ([[(j * args.per_belief + m) * 7 % nf] for m in range(args.per_belief)] if kind == "frame"
                  else [[(j * args.sequence + i) % nf for i in range(args.sequence)]])
        for idx in groups:
            est = det.estimate([frames.evidence(det, i) for i in idx])
            stats[kind].append((est.h, est.g, prior, c_true))
            reads[kind].append((appd(true, belief)[1], {k: posterior(det.model, est.h, est.g, k, 0.5).appd
                                                        for k in KAPPAS}, float(det.model.appd.mean())))
        print(f"  belief {j + 1}/{args.beliefs + args.sequences} ({kind})", flush=True)
    fitted = {kind: calibrated_kappa(s) for kind, s in stats.items()}
    frames_of = {"frame": 1, "sequence": args.sequence}
    b = np.log(fitted["sequence"] / fitted["frame"]) / np.log(frames_of["sequence"])
    print(f"calibrated kappa: {fitted}; kappa = {fitted['frame']:.3g} * frames ** {b:.3f}")
    for kind, s in stats.items():
        for k in (1.0, fitted[kind], 30.0):
            d = [mahalanobis(h, g, p, c, k) for h, g, p, c in s]
            print(f"  {kind}: kappa {k:.3g}: mean d2/K {np.mean(d):.2f}, median {np.median(d):.2f}")
        y = np.array([r[0] for r in reads[kind]])
        base = np.abs(np.array([r[2] for r in reads[kind]]) - y).mean()
        print(f"  {kind}: MAE / mean predictor's by kappa: " + ", ".join(
            f"{k:g}: {np.abs(np.array([r[1][k] for r in reads[kind]]) - y).mean() / base:.3f}" for k in KAPPAS))


if __name__ == "__main__":
    main()
