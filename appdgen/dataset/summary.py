"""build.json: what a build was asked (its plan, the names as given, the command), what it wrote (counts, shards),
how fast (per stage, wall and CPU seconds) and with which libraries (the ones that shape the bytes)."""
from __future__ import annotations

import platform
import sys
from collections import Counter

import cv2
import numpy as np

from appdgen.dataset.encoders import get_encoder
from appdgen.dataset.layout import STAGES, ShardStats
from appdgen.dataset.plan import BuildConfig


def summary(config: BuildConfig, shard_stats: list[ShardStats], built: list[int], seconds: float,
             command: list[str] | None, skipped: list[dict]) -> dict:
    """build.json: what was asked, what was written, how fast, with which libraries."""
    splits: Counter = Counter()
    for stats in shard_stats:
        splits.update(stats.splits)
    made = [s for s in shard_stats if s.shard in set(built)]
    drawn = sum(s.samples - s.references for s in shard_stats)
    return {
        **config.record(),
        "command": command or sys.argv,
        "counts": {"samples": config.samples, "shards": config.shard_count, "splits": dict(sorted(splits.items())),
                   "references": sum(s.references for s in shard_stats), "images": len(config.images),
                   "skipped_images": skipped},
        "shards": [s.listing() for s in shard_stats],
        "sampler": {"evaluations_per_sample": sum(s.evaluations for s in shard_stats) / max(drawn, 1),
                    "seconds_per_sample": sum(s.stage_seconds["sample"] for s in shard_stats) / max(drawn, 1)},
        "timings": {"wall_seconds": seconds, "shards_built": len(made),
                    "shards_resumed": config.shard_count - len(made),
                    "samples_per_second": sum(s.samples for s in made) / seconds if seconds > 0 else None,
                    "mb_written": sum(s.bytes for s in made) / 1e6,
                    # Worker seconds per stage over this run's shards (all workers together).
                    "stage_seconds": {k: sum(s.stage_seconds[k] for s in made) for k in STAGES},
                    # … and their CPU seconds (below stage_seconds' sum where a worker waited: disk, a busy core).
                    "cpu_seconds": sum(s.cpu_seconds for s in made)},
        "libraries": versions(config),
    }


def versions(config: BuildConfig) -> dict:
    """Versions of Python and the libraries that shape the bytes (the PNG encoder's own package among them)."""
    import joblib
    import pyarrow
    import simplejpeg  # decodes JPEG inputs (sources/decode.py)

    encoder = get_encoder(config.encoder, config.channels)
    png = {encoder.library: encoder.version()} if config.image_format == "png" else {}
    return {"python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
            "pyarrow": pyarrow.__version__, "joblib": joblib.__version__, "simplejpeg": simplejpeg.__version__,
            **png}
