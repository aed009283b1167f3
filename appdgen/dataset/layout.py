"""The output layout of a build, the one owner of its names: files, shard naming, image formats, label columns.

The writer (shards.BuildWriter), the reader (reader.open_build), resume, `inspect`, `verify`, the trainer and the
benchmarks all take these names from here, and so does the CLI for its choices. A build folder holds

    OUT/shard-000000.tar …   WebDataset shards: <key>.json then <key><ext> per sample, key = 9-digit sample index
    OUT/labels.parquet       one row per sample (label_schema)
    OUT/build.json           the plan, counts, per-shard stats, timings, library versions
    OUT/.parts/              only while a build runs: plan.json and per-shard stats and label fragments
"""
from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pyarrow as pa

INDEX = "labels.parquet"
BUILD_JSON = "build.json"
PARTS_DIR = ".parts"
PLAN = "plan.json"
SHARD_PATTERN = "shard-{:06d}.tar"
SHARD_GLOB = "shard-*.tar"
SHARD_FILE = re.compile(r"shard-\d{6,}\.tar")
#: Names a build writes at the top of OUT besides its shards.
OUTPUT_NAMES = (INDEX, BUILD_JSON, PARTS_DIR)
#: --format choices → the image members' extension.
FORMATS: dict[str, str] = {"png": ".png", "jpg": ".jpg", "npy": ".npy"}
#: The image members' extensions as WebDataset names a sample's fields (no dot: 'png', 'jpg', 'npy').
SAMPLE_FIELDS: tuple[str, ...] = tuple(ext.lstrip(".") for ext in FORMATS.values())
#: The member that is the label row minus this column (its own bytes' hash).
HASH_COLUMN = "sha256"
#: The label, in % of the raw image diagonal: what the trainer learns.
LABEL_COLUMN = "appd_pct"
#: The extension of a sample's label member (`<key>.json`).
RECORD_EXT = ".json"
RECORD_FIELD = RECORD_EXT.lstrip(".")  # … as WebDataset names that field
#: Each sample's crop R (crop.Crop: x0, y0, x1, y1 in undistorted normalized coordinates), so that any build's
#: labels are a bank of labelled calibrations (Θm, R, APPD) that can be rendered again without a search.
CROP_COLUMNS = ("crop_x0", "crop_y0", "crop_x1", "crop_y1")
#: Each sample's warp from the reference rectification split into affine part and rest (geometry.bend.split_warp):
#: the rest's mean length (raw px, and % of the raw diagonal like appd_pct), the affine part's shift at the image
#: centre (raw px) and its zoom. Computed from the row's own parameters and crop; a reference sample is 0, 0, 0, 0, 1.
BEND_LABEL = "bend_pct"
BEND_COLUMNS = ("bend_px", BEND_LABEL, "shift_x_px", "shift_y_px", "scale")
#: What a fit may learn (`python -m train fit --target`) → its label column: APPD (the paper's, the default) or its
#: non-affine part (sampling.sampler.TARGETS: the same names, and each one's value for a draw, for fit --online).
TARGETS: dict[str, str] = {"appd": LABEL_COLUMN, "bend": BEND_LABEL}
#: Columns of labels.parquet that the `<key>.json` members leave out: the hash, the crop and the bend (added after
#: builds had shipped; the members, hence the shards, keep their bytes).
INDEX_ONLY = (HASH_COLUMN, *CROP_COLUMNS, *BEND_COLUMNS)


def shard_name(index: int) -> str:
    """File name of shard `index`."""
    return SHARD_PATTERN.format(index)


def sample_key(index: int) -> str:
    """WebDataset key of sample `index` (sorts in sample order)."""
    return f"{index:09d}"


def member_names(key: str, ext: str) -> tuple[str, str]:
    """A sample's two tar members, in the order they are written: its label record, then its image."""
    return f"{key}{RECORD_EXT}", f"{key}{ext}"


def fragment_name(shard: int) -> str:
    """Name under PARTS_DIR of one shard's label rows (Parquet, its ShardStats in the metadata under STATS_KEY),
    written last: it marks the shard done."""
    return f"{shard_name(shard)}.parquet"


FRAGMENT_GLOB = "shard-*.tar.parquet"  # fragment_name of any shard
STATS_KEY = b"appdgen.shard_stats"
#: The stages of building a sample, timed per shard (ShardStats.stage_seconds, build.json timings): decode the raw
#: image, sample Θm (search, crop, maps M̂, APPD label), remap, encode, write (hash, tar member, shard sync).
STAGES = ("decode", "sample", "remap", "encode", "write")


#: Where a frame of a recording (bag, video) came from, after the label columns of a build from recordings:
#: the recording as given, its topic ("" for a video), the bag's receive time or the video's presentation time
#: (ns), and the frame's number in the topic or video (from 0). Name → pyarrow type name.
SOURCE_COLUMNS = (("source", "string"), ("topic", "string"), ("timestamp_ns", "int64"), ("frame", "int64"))


def label_schema(params: Sequence[str], sources: bool = False, crop: bool = True, bend: bool = True) -> pa.Schema:
    """labels.parquet columns for a lens model's parameters `params` (fx, fy, cx, cy, then its coefficients),
    with SOURCE_COLUMNS for a build from recordings (`sources`); crop=False / bend=False: without CROP_COLUMNS /
    BEND_COLUMNS, as builds before them wrote it.

    Units: parameters in raw pixels (fx…cy) or unitless (coefficients); new_* in output pixels; crop_* in
    undistorted normalized coordinates; appd_px in raw pixels, appd_pct in % of the raw diagonal; bend_px,
    shift_x_px, shift_y_px in raw pixels, bend_pct in % of the raw diagonal, scale unitless (> 1: a wider view).
    """
    import pyarrow as pa  # here, not at the top: the image codecs and synth import this module for FORMATS alone

    return pa.schema([
        ("key", pa.string()), ("shard", pa.string()), ("raw_path", pa.string()), ("split", pa.string()),
        ("camera", pa.string()), ("model", pa.string()), ("sample_index", pa.int64()), ("is_reference", pa.bool_()),
        *[(name, pa.float64()) for name in params],
        ("new_fx", pa.float64()), ("new_fy", pa.float64()), ("new_cx", pa.float64()), ("new_cy", pa.float64()),
        ("width", pa.int32()), ("height", pa.int32()), ("appd_px", pa.float64()), ("appd_pct", pa.float64()),
        (HASH_COLUMN, pa.string()),
        *[(name, pa.float64()) for name in (CROP_COLUMNS if crop else ())],
        *[(name, pa.float64()) for name in (BEND_COLUMNS if bend else ())],
        *((name, getattr(pa, kind)()) for name, kind in (SOURCE_COLUMNS if sources else ())),
    ])


def known_schemas(params: Sequence[str], sources: bool = False) -> tuple[pa.Schema, ...]:
    """Every label schema appdgen has written for these parameters, newest first: with crop and bend, with the crop
    only (0.3.0 before the bend), with neither."""
    return (label_schema(params, sources), label_schema(params, sources, bend=False),
            label_schema(params, sources, crop=False, bend=False))


def crop_columns(x0: float, y0: float, x1: float, y1: float) -> dict[str, float]:
    """A crop rectangle (normalized coordinates) as its CROP_COLUMNS values."""
    return dict(zip(CROP_COLUMNS, (float(x0), float(y0), float(x1), float(y1)), strict=True))


def source_columns(source: str, topic: str, timestamp_ns: int, frame: int) -> dict:
    """A recording's frame (the recording as given, topic, timestamp ns, number from 0) as its SOURCE_COLUMNS values."""
    values = (source, topic, timestamp_ns, frame)
    return {name: value for (name, _), value in zip(SOURCE_COLUMNS, values, strict=True)}


def bend_columns(bend_px: float, bend_pct: float, shift_x_px: float, shift_y_px: float,
                 scale: float) -> dict[str, float]:
    """A warp's split (raw px, % of the diagonal, unitless scale) as its BEND_COLUMNS values."""
    return dict(zip(BEND_COLUMNS, (float(bend_px), float(bend_pct), float(shift_x_px), float(shift_y_px),
                                   float(scale)), strict=True))


def member_record(row: dict) -> dict:
    """A sample's `<key>.json` content: its label row minus the INDEX_ONLY columns."""
    return {k: v for k, v in row.items() if k not in INDEX_ONLY}


def record_json(row: dict) -> bytes:
    """The `<key>.json` member's bytes for a label row: member_record, keys sorted, floats in full precision."""
    return json.dumps(member_record(row), sort_keys=True, separators=(",", ":")).encode("utf-8")


@dataclass
class ShardStats:
    """What a worker reports for one finished shard (kept under PARTS_DIR until the build ends)."""

    shard: int
    file: str
    samples: int
    bytes: int
    splits: dict[str, int]
    references: int
    evaluations: int  # APPD evaluations of the sampler's searches
    stage_seconds: dict[str, float]  # per STAGES name
    seconds: float
    cpu_seconds: float = 0.0  # the worker's CPU time over the shard (process_time): wall minus waiting

    def to_json(self) -> bytes:
        """JSON bytes (stable key order)."""
        return json.dumps(asdict(self), sort_keys=True).encode()

    @classmethod
    def from_json(cls, data: bytes | str) -> "ShardStats":
        """Read back what to_json wrote."""
        return cls(**json.loads(data))

    def listing(self) -> dict:
        """The shard's entry in build.json's `shards` list."""
        return {"file": self.file, "samples": self.samples, "bytes": self.bytes, "splits": self.splits}
