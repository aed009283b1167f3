"""The classical floor (train.plumbline) on fresh pairs: ridge on plumb-line features, scored on frames it
was not fitted on, for appd_pct and bend_pct, at a raw size scaled by --scale (0.25 → 348×128).

Each frame i is a new synthetic street (synth.render_frame, seed [seed, i]) seen through the reference camera and
rectified with the build sampler's draw(seed, i) at the raw size (or --size, as fit --online's --size): every test
frame is an unseen scene under an unseen calibration. Prints, per target, the out-of-fold MAE / mean-predictor MAE
(--folds interleaved folds, each frame predicted by a fit on the others, against their mean) and Spearman ρ, and the
time of line_features per image.

Run: python -m studies.plumbline [--frames 160] [--scale 0.25] [--seed 0] [--folds 5] [--size WxH]
"""
from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from appdgen.analysis.studies import spearman
from appdgen.calib.defaults import default_calibration
from appdgen.geometry.appd import px_to_pct
from appdgen.geometry.remap import remap_image
from appdgen.sampling.sampler import Sampler, target_px
from appdgen.synth import frame_rng, render_frame, scale_calibration
from appdgen.util.sizes import parse_size
from train.plumbline import PlumbLine, feature_matrix


def pairs(scenes: int, scale: float, seed: int, draws: int = 1, size: tuple[int, int] | None = None
          ) -> tuple[list[np.ndarray], dict[str, np.ndarray]]:
    """Rectified images (at `size`, default the raw size) of fresh pairs, `draws` calibrations per street (pair i =
    scene i // draws under the sampler's draw(seed, i)), and their targets appd_pct, bend_pct (% of the raw
    diagonal)."""
    reference = scale_calibration(default_calibration(), scale)
    sampler = Sampler(reference, appd_max=1.0, labels=True, size=size)
    images, appd, bend = [], [], []
    for scene in range(scenes):
        raw = render_frame(reference, frame_rng(seed, scene))
        for i in range(scene * draws, (scene + 1) * draws):
            draw = sampler.draw(seed, i)
            images.append(remap_image(raw, draw.rect))
            appd.append(px_to_pct(draw.appd_px, reference))
            bend.append(px_to_pct(target_px(sampler, draw, "bend"), reference))
    return images, {"appd_pct": np.array(appd), "bend_pct": np.array(bend)}


def score(x: np.ndarray, y: np.ndarray, alpha: float | None, folds: int, draws: int = 1
          ) -> tuple[float, float, float]:
    """(MAE / mean-predictor MAE, Spearman ρ, median alpha) of out-of-fold predictions: each pair predicted by a
    fit on the other folds (streets s ≡ f mod folds, s = i // draws: no street on both sides), against that fit's
    training mean."""
    predicted, baseline, alphas = np.empty_like(y), np.empty_like(y), []
    for fold in range(folds):
        test = np.arange(len(y)) // draws % folds == fold
        model = PlumbLine().fit_features(x[~test], y[~test], alpha)
        predicted[test], baseline[test] = model.predict_features(x[test]), y[~test].mean()
        alphas.append(model.alpha)
    ratio = np.abs(predicted - y).mean() / np.abs(baseline - y).mean()
    return float(ratio), spearman(predicted, y), float(np.median(alphas))


def main() -> None:
    """Render, featurise, fit and print the ratios."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=160)
    parser.add_argument("--scale", type=float, default=0.25)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--size", help="output WxH (default the raw size), e.g. 348x128 from --scale 1 frames")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    images, targets = pairs(args.frames, args.scale, args.seed, size=parse_size(args.size))
    start = time.perf_counter()
    x = feature_matrix(images)
    per_image = (time.perf_counter() - start) / len(images)
    h, w = images[0].shape[:2]
    print(f"{len(images)} frames at {w}x{h}: line_features {per_image * 1e3:.1f} ms per image (one thread)")
    for name, y in targets.items():
        for alpha in (1.0, None):
            ratio, rho, chosen = score(x, y, alpha, args.folds)
            print(f"{name}: alpha {chosen:g}{' (CV, median over folds)' if alpha is None else ''}: out-of-fold MAE / "
                  f"mean-predictor MAE {ratio:.3f}, Spearman rho {rho:.3f}")


if __name__ == "__main__":
    main()
