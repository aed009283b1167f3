"""A build's worker: one shard's samples drawn, remapped from their raw images and encoded into the shard's tar
(streamed, written atomically), with their label rows and the shard's stats for the parent to record."""
from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import cv2

from appdgen.calib.calibration import Calibration
from appdgen.dataset.images import encode_image
from appdgen.dataset.layout import (
    STAGES,
    ShardStats,
    bend_columns,
    crop_columns,
    sample_key,
    shard_name,
    source_columns,
)
from appdgen.dataset.plan import BuildConfig
from appdgen.geometry.appd import px_to_pct
from appdgen.geometry.bend import split_warp
from appdgen.geometry.crop import Crop
from appdgen.geometry.maps import Rectification
from appdgen.geometry.remap import remap_image
from appdgen.sources.frames import Frame, RawImage
from appdgen.sources.raw import RawReader


def build_shard(job: tuple[BuildConfig, str, int]) -> tuple[ShardStats, list[dict]]:
    """Build one shard's tar in a worker; returns its stats and label rows (the parent writes the fragment, so
    workers never load pandas, which pyarrow imports on first use: 0.2 s of each worker's start)."""
    config, out_dir, shard = job
    cv2.setNumThreads(1)  # the parent decides parallelism
    out = Path(out_dir)
    start, cpu = time.perf_counter(), time.process_time()
    sampler = config.sampler()
    rows, evaluations, spent = [], 0, dict.fromkeys(STAGES, 0.0)
    last = time.perf_counter()

    def lap(stage: str) -> None:
        """Add the time since the last lap to a stage."""
        nonlocal last
        now = time.perf_counter()
        spent[stage] += now - last
        last = now

    raws = RawReader(map(config.image_for, config.shard_samples(shard)))
    # Streamed to disk as it grows: a 1,000-sample full-size shard would be ~1 GB in memory.
    with config.writer(out).shard(shard) as tar:
        for index in config.shard_samples(shard):
            draw = sampler.draw(config.seed, index)
            evaluations += draw.evaluations
            bend = warp_columns(config.reference, sampler.reference_rect.crop, draw.calib, draw.rect.crop)
            lap("sample")
            raw_image = config.image_for(index)
            raw = raws.read(raw_image, config.channels)
            lap("decode")
            image = remap_image(raw, draw.rect, config.interp)
            lap("remap")
            data = encode_image(image, config.ext, config.encoder)
            lap("encode")
            row = _label_row(config, shard, index, raw_image, draw.is_reference, draw.rect, draw.appd_px, bend)
            tar.add_sample(row, config.ext, data)
            rows.append(row)
            lap("write")
    lap("write")
    raws.close()
    stats = ShardStats(shard=shard, file=shard_name(shard), samples=len(rows), bytes=tar.size,
                       splits=dict(sorted(Counter(r["split"] for r in rows).items())),
                       references=sum(r["is_reference"] for r in rows), evaluations=evaluations,
                       stage_seconds=spent, seconds=time.perf_counter() - start,
                       cpu_seconds=time.process_time() - cpu)
    return stats, rows


def warp_columns(reference: Calibration, reference_crop: Crop, calib: Calibration, crop: Crop) -> dict[str, float]:
    """A sample's layout.BEND_COLUMNS: split_warp from the reference rectification (raw px, % of the raw diagonal,
    unitless scale); a reference sample exactly 0, 0, 0, 0, 1."""
    split = split_warp(reference, reference_crop, calib, crop)
    return bend_columns(split.bend_px, px_to_pct(split.bend_px, reference), split.shift_x_px, split.shift_y_px,
                        split.scale)


def _label_row(config: BuildConfig, shard: int, index: int, image: RawImage, is_reference: bool,
               rect: Rectification, distance_px: float, bend: dict[str, float]) -> dict:
    """One sample's label: perturbed Θ, K̂ of its crop, output size, APPD (px and % of the diagonal), its crop and
    its warp's split (`bend`, warp_columns)."""
    k = rect.new_camera_matrix
    return {
        "key": sample_key(index), "shard": shard_name(shard), "raw_path": image.name, "split": image.split,
        "camera": config.camera, "model": rect.calib.model, "sample_index": index, "is_reference": bool(is_reference),
        **rect.calib.params(),
        "new_fx": float(k[0, 0]), "new_fy": float(k[1, 1]), "new_cx": float(k[0, 2]), "new_cy": float(k[1, 2]),
        "width": config.size[0], "height": config.size[1],
        "appd_px": distance_px, "appd_pct": px_to_pct(distance_px, config.reference),
        **crop_columns(rect.crop.x0, rect.crop.y0, rect.crop.x1, rect.crop.y1), **bend,
        **(_frame_columns(image.frame) if image.frame is not None else {}),
    }


def _frame_columns(frame: Frame) -> dict:
    """A recording's frame as its labels.parquet source columns."""
    return source_columns(frame.source, frame.topic, frame.timestamp_ns, frame.number)
