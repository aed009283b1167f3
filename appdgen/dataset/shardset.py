"""A build's shards as a consumer (the trainer, the benchmarks) reads them back: the shard set (through the build
reader, or found by name without build.json), the label columns it trains on, and a sample's stored image decoded.
No torch: the stream over them is train.data's."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from appdgen.dataset import images
from appdgen.dataset.layout import (
    BUILD_JSON,
    FORMATS,
    INDEX,
    LABEL_COLUMN,
    SAMPLE_FIELDS,
    SHARD_GLOB,
    SOURCE_COLUMNS,
    TARGETS,
)
from appdgen.dataset.reader import ShardEntry as Shard
from appdgen.dataset.reader import index_columns, open_build
from appdgen.errors import AppdgenError

try:
    import pyspng
except ImportError:  # an install without the train extra's pyspng: OpenCV decodes the PNGs (same pixels)
    pyspng = None


@dataclass(frozen=True)
class ShardSet:
    """What `appdgen build` wrote into a folder: shards, image size (w, h in pixels), APPD range (%)."""

    root: Path
    shards: tuple[Shard, ...]
    size: tuple[int, int] | None
    appd_max: float | None
    build: Mapping = field(default_factory=dict)

    def split_count(self, split: str) -> int:
        """Samples of one split over all shards."""
        return sum(s.splits.get(split, 0) for s in self.shards)

    def split_names(self) -> list[str]:
        """The splits the shards hold, sorted (none known for shards found by name)."""
        return sorted({name for s in self.shards for name, n in s.splits.items() if n})

    def for_split(self, split: str) -> tuple[Shard, ...]:
        """Only the shards that hold the split (saves reading the others)."""
        return tuple(s for s in self.shards if s.splits.get(split, 0) > 0)

    def rectify_rule(self) -> dict | None:
        """How the build rectified raw images (max_fov in degrees, None = unbounded; interp), None without build.json.

        A detector must see raw images rectified the same way at deployment, so fit records this in its checkpoint.
        """
        if not self.build:
            return None
        return {"max_fov": self.build.get("max_fov"), "interp": self.build.get("interp")}


def open_shards(root: str | Path) -> ShardSet:
    """The shards of a build folder, read through appdgen's build reader; without build.json, the shard files found
    by name with unknown split counts."""
    root = Path(root)
    if not root.is_dir():
        raise AppdgenError(f"{root}: no such shard folder (expected the output of `appdgen build`)")
    if not (root / BUILD_JSON).is_file():
        return _glob_shards(root)
    build = open_build(root)
    shards = build.entries
    if not shards:
        raise AppdgenError(f"{root / BUILD_JSON}: lists no shards")
    missing = [s.path for s in shards if not s.path.is_file()]
    if missing:
        raise AppdgenError(f"{root / BUILD_JSON}: {len(missing)} listed shard(s) missing, e.g. {missing[0]}")
    return ShardSet(root, shards, build.size, build.appd_max, build.info)


def _glob_shards(root: Path) -> ShardSet:
    """Shards found by name when build.json is missing; every shard is read for every split."""
    paths = sorted(root.glob(SHARD_GLOB))
    if not paths:
        raise AppdgenError(f"{root}: neither {BUILD_JSON} nor {SHARD_GLOB} found")
    everything = _AllSplits()
    return ShardSet(root, tuple(Shard(p, 0, everything) for p in paths), None, None)


class _AllSplits(dict):
    """A splits mapping that claims every split, for shards of unknown content."""

    def get(self, key: str, default: int = 0) -> int:  # noqa: ARG002 - dict signature
        """Any split may be present: 1 means 'read this shard'."""
        return 1


#: The label columns the trainer reads (and the recording's source, in a build from recordings).
LABEL_COLUMNS = ("key", "split", "raw_path", LABEL_COLUMN)


def read_labels(root: Path, target: str = "appd") -> dict[str, list] | None:
    """Columns key, split, raw_path, appd_pct, the target's label column (layout.TARGETS) and, for a build from
    recordings, source of the build's label table, or None when it has none (refused for a target other than
    appd, whose labels only the table holds)."""
    column = TARGETS[target]
    table = index_columns(Path(root), LABEL_COLUMNS, optional=[column, SOURCE_COLUMNS[0][0]])
    if column != LABEL_COLUMN and (table is None or column not in table.column_names):
        why = f"no {INDEX}" if table is None else f"its {INDEX} has no {column} column (built before it)"
        raise AppdgenError(f"{root}: --target {target} needs {column}, but {why}: rebuild it, or use --target appd")
    if table is None:
        return None
    cols = table.to_pydict()
    cols["key"] = [str(k) for k in cols["key"]]  # json keys are strings; match them whatever parquet typed
    return cols


def target_labels(labels: Mapping[str, list] | None, target: str) -> dict[str, float] | None:
    """key → the target's label from read_labels' columns, for a stream to use instead of the json members' appd_pct;
    None for appd (the members hold it)."""
    column = TARGETS[target]
    return None if column == LABEL_COLUMN or labels is None else dict(zip(labels["key"], labels[column], strict=True))


def decode_sample(data: bytes, ext: str, where: str) -> np.ndarray:
    """H×W×C uint8 image as stored (C 3: OpenCV BGR order, 1: grey) from a sample's encoded bytes; PNG through
    pyspng when installed (the train extra: the same pixels, decoded faster than by OpenCV, docs/performance.md)."""
    arr = _spng_decode(data, where) if ext == "png" and pyspng is not None else images.decode_image(data, f".{ext}",
                                                                                                  where)
    if arr.ndim == 2:  # a grey sample (a build with channels 1)
        arr = arr[:, :, None]
    if arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] not in (1, 3):
        raise AppdgenError(f"{where}: expected a 3-channel or grey 8-bit image, got {arr.dtype} {arr.shape}")
    return arr


def _spng_decode(data: bytes, where: str) -> np.ndarray:
    """A PNG's pixels through pyspng, colour in BGR order (a view: the loader's CHW copy makes it contiguous)."""
    try:
        arr = pyspng.load(data)
    except RuntimeError:
        raise AppdgenError(f"{where}: not a readable image") from None
    return arr[:, :, 2::-1] if arr.ndim == 3 and arr.shape[2] == 3 else arr


def image_entry(sample: Mapping) -> tuple[str, bytes]:
    """(extension, bytes) of a webdataset sample's image member."""
    for ext in SAMPLE_FIELDS:
        if ext in sample:
            return ext, sample[ext]
    raise AppdgenError(f"{sample.get('__url__')}: sample {sample.get('__key__')} has no "
                       f"{'/'.join(FORMATS.values())} image")
