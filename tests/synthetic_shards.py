"""Tiny stand-in builds with a learnable label, for tests and benchmarks, written by appdgen's build writer."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.dataset.encoders import DEFAULT_ENCODER, ENCODERS
from appdgen.dataset.images import encode_image
from appdgen.dataset.layout import FORMATS, STAGES, ShardStats, bend_columns, crop_columns, sample_key, shard_name
from appdgen.dataset.shards import BuildWriter

INTRINSICS = {"fx": 100.0, "fy": 100.0, "cx": 64.0, "cy": 64.0, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}
CAMERA = "00"


def texture(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """A smooth random colour texture, H×W×3 float in [0, 1] (a stand-in for a raw camera image)."""
    small = rng.random((max(2, h // 16), max(2, w // 16), 3)).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 1)


def sample_image(base: np.ndarray, gain: float) -> np.ndarray:
    """The raw texture darkened by gain: brightness carries the label."""
    return (base * gain * 255).round().astype(np.uint8)


def write_shards(
    out: str | Path,
    n: int = 64,
    size: tuple[int, int] = (128, 128),
    per_shard: int = 16,
    splits: tuple[tuple[str, int], ...] = (("train", 3), ("test", 1)),
    fmt: str = "png",
    appd_max: float = 3.0,
    per_raw: int = 4,
    seed: int = 0,
) -> Path:
    """Write n samples as a build folder (shards, label table, summary); label = appd_max·(gain−0.2)/0.8 in %.

    Samples come in groups of per_raw sharing one raw texture (a 'raw image'); raw images cycle
    through `splits` by weight, so a split never shares raw images with another.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    w, h = size
    reference = Calibration(w, h, *INTRINSICS.values())
    writer = BuildWriter(out, reference.param_names)
    cycle = [name for name, weight in splits for _ in range(weight)]
    base = texture(rng, w, h)
    made = {}
    for shard in range(-(-n // per_shard)):
        rows: list[dict] = []
        with writer.shard(shard) as tar:
            for i in range(shard * per_shard, min(n, (shard + 1) * per_shard)):
                if i % per_raw == 0:
                    base = texture(rng, w, h)
                gain = float(rng.uniform(0.2, 1.0))
                row = _row(i, shard, cycle[i // per_raw % len(cycle)], i // per_raw, appd_max * (gain - 0.2) / 0.8,
                           reference)
                tar.add_sample(row, FORMATS[fmt], encode_image(sample_image(base, gain), FORMATS[fmt]))
                rows.append(row)
        stats = ShardStats(shard=shard, file=shard_name(shard), samples=len(rows), bytes=tar.size,
                           splits=dict(sorted(Counter(r["split"] for r in rows).items())), references=0,
                           evaluations=0, stage_seconds=dict.fromkeys(STAGES, 0.0), seconds=0.0)
        made[shard] = writer.shard_done(stats, rows)
    writer.finish(len(made), made, lambda stats: _summary(stats, reference, fmt, appd_max, per_shard, seed))
    return out


def _row(index: int, shard: int, split: str, raw: int, appd_pct: float, reference: Calibration) -> dict:
    """One sample's label row (the build's label columns; K̂ is the reference's: nothing is cropped, so R is the
    frame, [−0.5, w−0.5] × [−0.5, h−0.5] in normalized coordinates; the bend is made up like the label: half of it,
    so that a fit on either target has something to learn)."""
    fx, fy, cx, cy = (INTRINSICS[k] for k in ("fx", "fy", "cx", "cy"))
    appd_px = appd_pct / 100 * float(np.hypot(reference.width, reference.height))
    return {
        "key": sample_key(index), "shard": shard_name(shard), "raw_path": f"raw/rec{raw % 3}/{raw:06d}.png",
        "split": split, "camera": CAMERA, "model": reference.model, "sample_index": index, "is_reference": False,
        **INTRINSICS, **{f"new_{k}": INTRINSICS[k] for k in ("fx", "fy", "cx", "cy")},
        "width": reference.width, "height": reference.height,
        "appd_px": appd_px, "appd_pct": appd_pct,
        **crop_columns((-0.5 - cx) / fx, (-0.5 - cy) / fy, (reference.width - 0.5 - cx) / fx,
                       (reference.height - 0.5 - cy) / fy),
        **bend_columns(appd_px / 2, appd_pct / 2, 0.0, 0.0, 1.0),
    }


def _summary(shard_stats: list[ShardStats], reference: Calibration, fmt: str, appd_max: float, per_shard: int,
             seed: int) -> dict:
    """The summary a build writes, with what the trainer, `inspect` and `verify` read."""
    splits: Counter = Counter()
    for stats in shard_stats:
        splits.update(stats.splits)
    samples = sum(s.samples for s in shard_stats)
    return {
        "appdgen_version": "synthetic", "calibration": {"camera": CAMERA, **reference.to_dict()}, "samples": samples,
        "size": [reference.width, reference.height], "format": fmt, "shard_size": per_shard, "seed": seed,
        "appd_max": appd_max, "encoder": DEFAULT_ENCODER,
        # what verify re-encodes with: the PNG encoder's library at the version that wrote the bytes
        "libraries": {ENCODERS[DEFAULT_ENCODER].library: ENCODERS[DEFAULT_ENCODER].version()},
        "counts": {"samples": samples, "shards": len(shard_stats), "splits": dict(sorted(splits.items())),
                   "references": 0},
        "shards": [s.listing() for s in shard_stats],
    }
