"""How much of an APPD label can one image show? Splits each sample's warp into what an affine map explains and
the rest.

A sample image is the reference rectification warped by W(p) = K̂*·undistort(M̂m(p); Θ*) in reference output
pixels. A translation or a zoom of the whole picture (the affine part of W) leaves straight lines straight, so a
single image only shows it through scene priors; the non-affine rest (bent lines) is what the CNN can measure.
Prints, for a build's labels.parquet and for one-parameter perturbations at the range edges, APPD and the mean
non-affine displacement: APPD in raw pixels, the rest in output pixels (one unit when the
build kept the raw size).

Run: python -m studies.visibility demo/shards [--samples 150]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.dataset.reader import open_build
from appdgen.geometry.appd import appd_px
from appdgen.geometry.bend import affine_rest
from appdgen.geometry.distortion import undistort_pixels
from appdgen.geometry.maps import Rectification, rectify
from appdgen.sampling.ranges import parse_ranges

STRIDE = 4  # output pixels between evaluated grid points: the split is smooth, a coarse grid suffices


def warp_px(ref: Rectification, perturbed: Rectification) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Grid points (u, v) and the warp's displacement (du, dv) on them, in reference output pixels."""
    k = ref.new_camera_matrix
    h, w = ref.map_x.shape
    v, u = np.mgrid[0:h:STRIDE, 0:w:STRIDE].astype(np.float64)
    x, y = undistort_pixels(perturbed.map_x[::STRIDE, ::STRIDE], perturbed.map_y[::STRIDE, ::STRIDE], ref.calib)
    return u.ravel(), v.ravel(), (k[0, 0] * x + k[0, 2] - u).ravel(), (k[1, 1] * y + k[1, 2] - v).ravel()


def non_affine_px(u: np.ndarray, v: np.ndarray, du: np.ndarray, dv: np.ndarray) -> float:
    """Mean length (pixels) of the displacement left after the least-squares affine fit (geometry.bend.affine_rest)."""
    rest = affine_rest(u, v, du, dv)
    return float(np.hypot(rest.rest_u, rest.rest_v).mean())


def split(ref: Rectification, calib: Calibration) -> tuple[float, float]:
    """(APPD in raw pixels, mean non-affine displacement in output pixels) of one perturbed calibration."""
    rect = rectify(calib, ref.size)
    return appd_px(ref, rect), non_affine_px(*warp_px(ref, rect))


def main() -> None:
    """Print the split for a sample of the build's labels and for each parameter at its range edges."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shards", type=Path)
    ap.add_argument("--samples", type=int, default=150)
    args = ap.parse_args()
    build = open_build(args.shards)
    ref_calib = build.reference
    ranges = parse_ranges(",".join(f"{k}={v}" for k, v in build.options["ranges"].items()))
    table = build.labels().to_pandas()
    size = (int(table.width.iloc[0]), int(table.height.iloc[0]))
    ref = rectify(ref_calib, size)
    rows = table.sample(min(args.samples, len(table)), random_state=0)
    pairs = np.array([split(ref, ref_calib.replace(**{p: r[p] for p in ref_calib.param_names}))
                      for _, r in rows.iterrows()])
    appd, rest = pairs[:, 0], pairs[:, 1]
    print(f"{len(rows)} samples of {args.shards}: mean APPD {appd.mean():.2f} px, mean non-affine part "
          f"{rest.mean():.2f} px ({rest.mean() / appd.mean():.0%}); "
          f"correlation with APPD {np.corrcoef(appd, rest)[0, 1]:.2f}")
    print("one parameter at a time, at the build's range edges:")
    for name in ref_calib.param_names:
        for edge in ranges[name].offsets(getattr(ref_calib, name)):
            if edge == 0:
                continue
            a, r = split(ref, ref_calib.replace(**{name: getattr(ref_calib, name) + edge}))
            print(f"  {name} {edge:+10.4g}: APPD {a:5.2f} px, non-affine {r:5.2f} px ({r / a:4.0%})")


if __name__ == "__main__":
    main()
