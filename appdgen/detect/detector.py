"""The detector: how far a believed calibration is from the camera that took the frames, read from straight edges.

Frames are rectified with the belief as `appdgen build` rectifies its reference; their line evidence (edges) is
solved for the belief's field model (model) in one robust solve per frame or sequence (solve); the error model
weighs that evidence with what a real scene adds to it (errormodel), and the posterior over the sampling prior's
library gives APPD, bend and parameter offsets with honest sds (posterior). Frames whose edges barely move (a
hover) cannot tell a scene edge's own curvature from the lens's bend: they say so and, without a baseline, never
flag. Frames whose field no miscalibration explains (blur, low light) say so too, and their ± widens.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.detect.baseline import Baseline
from appdgen.detect.edges import EdgeParams, EdgePoints, edge_points
from appdgen.detect.errormodel import MIN_SEGMENTS, SCENE_FLOOR, likelihood
from appdgen.detect.model import FieldModel, belief_crop, cached_model
from appdgen.detect.posterior import posterior
from appdgen.detect.simulate import SIMULATED, learn_map
from appdgen.detect.solve import Design, Estimate, SolveParams, pool, solve
from appdgen.detect.tracks import track_ids, travel
from appdgen.errors import AppdgenError
from appdgen.geometry.maps import rectify
from appdgen.geometry.remap import remap_image
from appdgen.sources.decode import as_channels

DEFAULT_THRESHOLD_PCT = 0.5  # APPD in % of the raw diagonal above which a belief is "miscalibrated"
DEFAULT_SEQUENCE = 10  # frames pooled per sequence
SURE = 0.95  # p_above at or over this: "miscalibrated"; at or under 1 − SURE: "ok"
#: px: a sequence whose scene edges move less than this (median, normal to themselves) is a hover.
HOVER_PX = 6.0
HOVER = "frames barely move: a scene edge's own curvature cannot be told from lens bend"
#: The likelihood's dispersion (errormodel) at or over this: the edges' field is one no miscalibration explains.
MISFIT = 2.0
MISFIT_REASON = ("the edges read a field no miscalibration explains (blur, low light or the scene's own bend;"
                 " χ² {:.0f}x its expectation): ± widened")


@dataclass(frozen=True)
class Evidence:
    """One frame's line evidence: its name, segments found, and the edge points (belief output px)."""

    name: str
    segments: int
    points: EdgePoints = field(repr=False, compare=False)
    seconds: float = field(default=0.0, compare=False)


@dataclass(frozen=True)
class Reading:
    """What a frame or a pooled sequence says about the belief (APPD and bend in % of the raw diagonal; offsets:
    true − belief in each parameter's units, (mean, sd)); appd_pct None when it abstains, with the reason."""

    frames: int
    segments: int
    appd_pct: float | None
    appd_sd_pct: float | None
    bend_pct: float | None
    bend_sd_pct: float | None
    p_above: float | None
    threshold_pct: float
    offsets: dict[str, tuple[float, float]]
    reason: str | None
    can_flag: bool = True  # False: the evidence cannot tell the scene from the lens (a hover without a baseline)
    raw_appd_pct: float | None = None  # before the baseline's camera map (None: no map applied)
    raw_appd_sd_pct: float | None = None

    @property
    def verdict(self) -> str:
        """"abstain", "miscalibrated" (p_above ≥ 0.95 where the evidence can flag), "ok" (p_above ≤ 0.05) or
        "uncertain"."""
        if self.appd_pct is None or self.p_above is None:
            return "abstain"
        if self.p_above >= SURE:
            return "miscalibrated" if self.can_flag else "uncertain"
        return "ok" if self.p_above <= 1.0 - SURE else "uncertain"

    def to_dict(self) -> dict:
        """JSON-ready fields, offsets as {name: {"mean": m, "sd": s}}, and the verdict."""
        return {"frames": self.frames, "segments": self.segments, "appd_pct": self.appd_pct,
                "appd_sd_pct": self.appd_sd_pct, "bend_pct": self.bend_pct, "bend_sd_pct": self.bend_sd_pct,
                "p_above": self.p_above, "threshold_pct": self.threshold_pct,
                "offsets": {k: {"mean": m, "sd": s} for k, (m, s) in self.offsets.items()},
                "reason": self.reason, "verdict": self.verdict, "raw_appd_pct": self.raw_appd_pct,
                "raw_appd_sd_pct": self.raw_appd_sd_pct}


def abstention(frames: int, segments: int, threshold_pct: float, reason: str) -> Reading:
    """A Reading that gives no number, only why."""
    return Reading(frames, segments, None, None, None, None, None, threshold_pct, {}, reason)


class Detector:
    """Reads how far a believed calibration is from the camera that took the frames, from straight edges."""

    def __init__(self, belief: Calibration, max_fov: float | None = None, *, cache_dir: Path | None = None,
                 progress: Callable[[str], None] | None = None, library_draws: int | None = None) -> None:
        start = time.perf_counter()
        self.belief = belief
        self.max_fov = max_fov
        self.cache_dir = cache_dir
        self.library_draws = library_draws
        self.model: FieldModel
        self.model, self.cached = cached_model(belief, max_fov, cache_dir, progress, library_draws)
        self.rect = rectify(belief, crop=belief_crop(belief, max_fov))
        self.edge_params = EdgeParams()
        self.solve_params = SolveParams()
        self.seconds_to_model = time.perf_counter() - start

    def rectify(self, raw: np.ndarray) -> np.ndarray:
        """Raw 8-bit grey or BGR frame at belief.size → the grey rectified image at raw size (as build's reference)."""
        if raw.ndim not in (2, 3) or raw.shape[1] != self.belief.width or raw.shape[0] != self.belief.height:
            shape = "x".join(str(x) for x in raw.shape[1::-1])
            raise AppdgenError(f"image is {shape} but the calibration is {self.belief.width}x{self.belief.height}")
        return remap_image(as_channels(raw, 1), self.rect)

    def evidence(self, raw: np.ndarray, name: str = "") -> Evidence:
        """Rectify a raw frame and find its line evidence."""
        start = time.perf_counter()
        points = edge_points(self.rectify(raw), self.edge_params)
        return Evidence(name, points.segments, points, time.perf_counter() - start)

    def design(self, points: EdgePoints, baseline: Baseline | None = None) -> Design:
        """The solve's observations of one frame's points under this model (a baseline's bias removed)."""
        n = points.normal[points.seg]
        mu, basis = self.model.field_at(points.u, points.v)
        y = points.e + np.einsum("ij,ij->i", n, mu)
        if baseline is not None:  # the scene's apparent field adds to the lens's: the edges read as f + bias
            y = y + np.einsum("ij,ij->i", n, baseline.bias_at(self.belief, self.max_fov, points.u, points.v))
        return Design(y, -np.einsum("ikj,ij->ik", basis, n), points.s, points.seg, points.segments)

    def estimate(self, evidence: Sequence[Evidence], baseline: Baseline | None = None) -> Estimate:
        """The pooled robust solve of the frames' evidence."""
        return self._solve(evidence, baseline)[0]

    def _solve(self, evidence: Sequence[Evidence], baseline: Baseline | None) -> tuple[Estimate, float]:
        """The pooled robust solve and how far its scene edges travel (px; tracks.travel)."""
        used = [e.points for e in evidence if e.segments]
        if not used:
            k = len(self.model.var)
            empty = Design(np.zeros(0), np.zeros((0, k)), np.zeros(0), np.zeros(0, int), 0)
            return solve(empty, self.model.var), 0.0
        ids = track_ids(used)
        designs = [self.design(p, baseline) for p in used]
        return solve(pool(designs, ids), self.model.var, self.solve_params), travel(used, ids)

    def read(self, evidence: Sequence[Evidence], baseline: Baseline | None = None,
             threshold_pct: float = DEFAULT_THRESHOLD_PCT, camera_map: bool = True) -> Reading:
        """One frame or a sequence pooled in one solve; abstains when the evidence is too weak. Against a baseline
        with a camera map (and camera_map), APPD, its sd and p_above are the map's (the posterior's kept as raw_*)."""
        if baseline is not None:
            baseline.check(self.belief)
        frames, found = len(evidence), sum(e.segments for e in evidence)
        if found == 0:
            return abstention(frames, 0, threshold_pct, "no straight edges found (blank or featureless image)")
        est, moved = self._solve(evidence, baseline)
        if est.segments < MIN_SEGMENTS:
            return abstention(frames, est.segments, threshold_pct,
                              f"too few straight segments ({est.segments} < {MIN_SEGMENTS})")
        spread = None if baseline is None else baseline.spread_in(self.model, self.belief, self.max_fov)
        like = likelihood(est, self.model.coefs, self.model.var, SCENE_FLOOR, spread)
        post = posterior(self.model, like, threshold_pct)
        offsets = {n: (float(m), float(s)) for n, m, s in zip(self.model.names, post.offsets, post.offsets_sd,
                                                                           strict=True)}
        hover = frames > 1 and moved < HOVER_PX
        reasons = [HOVER if baseline is not None else f"{HOVER} (no flag without a baseline)"] if hover else []
        if like.dispersion >= MISFIT:
            reasons.append(MISFIT_REASON.format(like.dispersion))
        reason = "; ".join(reasons) or None
        appd, appd_sd, p_above, raw, raw_sd = post.appd, post.appd_sd, post.p_above, None, None
        if camera_map and baseline is not None and baseline.camera_map is not None:
            raw, raw_sd = appd, appd_sd
            appd, appd_sd, p_above = baseline.camera_map.apply(appd, appd_sd, threshold_pct)
        return Reading(frames, est.segments, appd, appd_sd, post.bend, post.bend_sd, p_above,
                       threshold_pct, offsets, reason, not hover or baseline is not None, raw, raw_sd)

    def save_baseline(self, evidence: Sequence[Evidence], source: str, simulated: int = SIMULATED,
                      progress: Callable[[int, int], None] | None = None) -> Baseline:
        """How this camera and its scenery read under the calibration it was calibrated with (belief = REF), and
        the camera's map from baseline readings to APPD learnt from `simulated` beliefs around REF read on these
        frames (detect.simulate; 0: no map); progress(done, simulated) after each."""
        evidence = list(evidence)
        est = self.estimate(evidence)
        if est.segments < MIN_SEGMENTS:
            raise AppdgenError(f"{source}: too few straight segments for a baseline ({est.segments} < {MIN_SEGMENTS})")
        alone = self._fields_alone(evidence)
        baseline = self._record(evidence, source, est, alone)
        if simulated <= 0:
            return baseline

        def detector_for(calib: Calibration) -> Detector:
            return Detector(calib, self.max_fov, cache_dir=self.cache_dir, library_draws=self.library_draws)

        def outside(first: int, last: int) -> Baseline | None:
            """The baseline of the frames outside [first, last), their fields read alone reused; None when they
            have too few segments."""
            part = evidence[:first] + evidence[last:]
            part_est = self.estimate(part)
            if part_est.segments < MIN_SEGMENTS:
                return None
            return self._record(part, source, part_est, alone[:first] + alone[last:])

        return baseline.with_map(learn_map(self, evidence, outside, detector_for, simulated, progress))

    def _fields_alone(self, evidence: Sequence[Evidence]) -> list[np.ndarray | None]:
        """Each frame's field read alone (gy, gx, 2; output px), None where it has too few segments."""
        fields: list[np.ndarray | None] = []
        for frame in evidence:
            one = self.estimate([frame]) if frame.segments else None
            fields.append(self.model.field_of(one.c) if one is not None and one.segments >= MIN_SEGMENTS else None)
        return fields

    def _record(self, evidence: Sequence[Evidence], source: str, est: Estimate,
                alone: Sequence[np.ndarray | None]) -> Baseline:
        """The baseline of these frames from their pooled solve, with the spread of their fields read alone."""
        per_frame = np.array([f for f in alone if f is not None])
        return Baseline.record(self.belief, self.max_fov, self.model.grid_u, self.model.grid_v,
                               self.model.field_of(est.c), len(evidence), est.segments, source, per_frame)
