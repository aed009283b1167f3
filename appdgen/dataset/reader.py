"""Reading a finished build folder back: `open_build(OUT)` → Build, the one reader of what the build writes.

`inspect`, `verify`, the trainer and the benchmarks read a build through this module; every name in the folder
comes from appdgen.dataset.layout. The lower-level readers (check_finished, read_info, read_index) are public for
`verify`, which reports a damaged index or summary as a finding rather than refusing it.
"""
from __future__ import annotations

import json
import tarfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from appdgen import lens
from appdgen.calib.calibration import DEFAULT_MODEL, INTRINSICS, Calibration
from appdgen.dataset.images import decode_image
from appdgen.dataset.layout import (
    BUILD_JSON,
    FORMATS,
    FRAGMENT_GLOB,
    INDEX,
    PARTS_DIR,
    PLAN,
    SHARD_FILE,
    known_schemas,
    member_names,
)
from appdgen.errors import AppdgenError

#: build.json's keys that are the build's options (what `appdgen build` was asked for, besides its inputs).
OPTIONS = ("samples", "size", "format", "shard_size", "seed", "appd_max", "zero_fraction", "interp", "max_fov",
           "ranges")


def check_finished(out: Path) -> None:
    """Refuse a missing folder or an unfinished build (AppdgenError naming it)."""
    if not out.is_dir():
        raise AppdgenError(f"{out}: {'not a folder' if out.exists() else 'no such folder'}")
    parts = out / PARTS_DIR
    if parts.is_dir() or not (out / INDEX).exists():
        if not parts.is_dir():
            raise AppdgenError(f"{out}: not an appdgen build (no {INDEX})")
        raise AppdgenError(f"{out}: build not finished ({_progress(parts)}; no {INDEX} yet): "
                           f"finish it with the same 'appdgen build' command plus --resume")


def _progress(parts: Path) -> str:
    """'3 of 4 shards done' from an unfinished build's parts folder."""
    done = len(list(parts.glob(FRAGMENT_GLOB)))
    try:
        plan = json.loads((parts / PLAN).read_text())
        return f"{done} of {-(-plan['samples'] // plan['shard_size'])} shards done"
    except (OSError, ValueError, KeyError, TypeError, ZeroDivisionError):
        return f"{done} shards done"


def read_info(out: Path) -> dict:
    """build.json as a dict; AppdgenError naming the file when unreadable."""
    try:
        info = json.loads((out / BUILD_JSON).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise AppdgenError(f"{BUILD_JSON}: unreadable ({getattr(exc, 'strerror', None) or exc})") from None
    if not isinstance(info, dict) or not isinstance(info.get("counts"), dict):
        raise AppdgenError(f"{BUILD_JSON}: not an appdgen build summary (no counts)")
    return info


def model_params(info: dict) -> tuple[str, ...]:
    """The label columns' parameter names of a build, from the lens model build.json records."""
    calibration = info.get("calibration")
    model = calibration.get("model", DEFAULT_MODEL) if isinstance(calibration, dict) else DEFAULT_MODEL
    try:
        return (*INTRINSICS, *lens.params(str(model)))
    except AppdgenError as exc:
        raise AppdgenError(f"{BUILD_JSON}: {exc}") from None


def read_index(out: Path, info: dict, columns: Sequence[str] | None = None) -> pa.Table:
    """labels.parquet with a label schema of build.json's lens model, this version's or an older build's (only
    `columns` when given); AppdgenError naming the file otherwise."""
    schemas = known_schemas(model_params(info), from_recordings(info))
    try:
        table = pq.read_table(out / INDEX)
    except (OSError, pa.ArrowException) as exc:
        raise AppdgenError(f"{INDEX}: unreadable ({exc})") from None
    if not any(table.schema.equals(schema) for schema in schemas):
        missing = [n for n in schemas[0].names if n not in table.schema.names]
        raise AppdgenError(f"{INDEX}: columns differ from appdgen's label schema"
                           + (f" (missing {', '.join(missing)})" if missing else ""))
    return table.select(list(columns)) if columns is not None else table


def from_recordings(info: dict) -> bool:
    """Whether build.json's build took its frames from recordings (bags, videos): its labels have SOURCE_COLUMNS."""
    return bool(info.get("recordings_sha256"))


def index_columns(out: Path, columns: Sequence[str], optional: Sequence[str] = ()) -> pa.Table | None:
    """Some columns of labels.parquet as found (and those of `optional` it has), None when there is none: for a
    folder without build.json."""
    try:
        if not (out / INDEX).is_file():
            return None
        names = pq.read_schema(out / INDEX).names
        return pq.read_table(out / INDEX, columns=[*columns, *(n for n in optional if n in names)])
    except (OSError, pa.ArrowException) as exc:
        raise AppdgenError(f"{out / INDEX}: unreadable ({exc})") from None


def image_ext(info: dict) -> str:
    """The image members' extension ('.png', '.jpg', '.npy') from build.json's format."""
    ext = FORMATS.get(info.get("format"))
    if ext is None:
        raise AppdgenError(f"{BUILD_JSON}: format {info.get('format')!r} is not one of {', '.join(FORMATS)}")
    return ext


def reference_of(info: dict) -> Calibration:
    """The reference calibration Θ* that build.json records (size and parameters)."""
    calib = info.get("calibration")
    if not isinstance(calib, dict):
        raise AppdgenError(f"{BUILD_JSON}: no calibration recorded")
    model = str(calib.get("model", DEFAULT_MODEL))
    names = model_params(info)
    try:
        return Calibration(int(calib["width"]), int(calib["height"]), *(float(calib[n]) for n in names), model=model)
    except (KeyError, TypeError, ValueError) as exc:
        raise AppdgenError(f"{BUILD_JSON}: calibration incomplete ({exc!r})") from None


def shard_path(out: Path, name: str) -> Path:
    """The path of a shard named in the index or build.json; never a path they made up (e.g. '../x')."""
    if not SHARD_FILE.fullmatch(name):
        raise AppdgenError(f"{INDEX}: shard {name!r} is not a shard file name")
    return out / name


def read_members(path: Path, names: set[str]) -> dict[str, bytes]:
    """The bytes of some members of a tar shard, by name (members not found are left out)."""
    return dict(stream_members(path, names))


def stream_members(path: Path, names: set[str]) -> Iterator[tuple[str, bytes]]:
    """(name, bytes) of some members of a tar shard, in the shard's order, one member in memory at a time."""
    try:
        with tarfile.open(path, mode="r:") as tar:
            for member in tar:
                if member.name in names and member.isreg():
                    yield member.name, tar.extractfile(member).read()
    except (OSError, tarfile.TarError) as exc:
        raise AppdgenError(f"{path}: unreadable shard ({exc})") from None


def counts(column: pa.ChunkedArray) -> dict[str, int]:
    """How often each value occurs in a column, sorted by value."""
    return dict(sorted((c["values"].as_py(), c["counts"].as_py()) for c in pc.value_counts(column)))


@dataclass(frozen=True)
class ShardEntry:
    """One shard as build.json lists it: its path, sample count and samples per split."""

    path: Path
    samples: int
    splits: dict[str, int]


@dataclass(frozen=True)
class Build:
    """A finished build folder: its summary, reference calibration, crop rule, splits, shards and labels."""

    path: Path
    info: dict  # build.json
    reference: Calibration
    image_ext: str  # '.png', '.jpg' or '.npy'
    entries: tuple[ShardEntry, ...]

    @property
    def options(self) -> dict:
        """The options the build ran with (samples, size, format, shard_size, seed, appd_max, …)."""
        return {k: self.info[k] for k in OPTIONS if k in self.info}

    @property
    def model(self) -> str:
        """The lens model's name."""
        return self.reference.model

    @property
    def max_fov(self) -> float | None:
        """--max-fov in degrees (None: crops unbounded)."""
        return self.info.get("max_fov")

    @property
    def interp(self) -> str | None:
        """The remap interpolation's name."""
        return self.info.get("interp")

    @property
    def size(self) -> tuple[int, int]:
        """Output image size (w, h) in pixels."""
        return tuple(int(v) for v in self.info["size"])

    @property
    def appd_max(self) -> float | None:
        """The top of the label range, % of the raw diagonal."""
        value = self.info.get("appd_max")
        return None if value is None else float(value)

    @property
    def splits(self) -> dict[str, int]:
        """Samples per split."""
        return dict(self.info["counts"].get("splits") or {})

    @property
    def count(self) -> int:
        """Samples in the build."""
        return int(self.info["counts"].get("samples", sum(e.samples for e in self.entries)))

    @property
    def shards(self) -> tuple[Path, ...]:
        """The shard files, in order."""
        return tuple(e.path for e in self.entries)

    def labels(self, split: str | None = None, columns: Sequence[str] | None = None) -> pa.Table:
        """The label table (labels.parquet), one split's rows when given, only `columns` when given."""
        table = read_index(self.path, self.info)
        if split is not None:
            table = table.filter(pc.equal(table["split"], split))
        return table.select(list(columns)) if columns is not None else table

    def samples(self, split: str | None = None) -> Iterator[tuple[str, np.ndarray, dict]]:
        """(key, decoded image, label row) of every sample (of one split), in sample order, one shard read at a time."""
        rows = self.labels(split).sort_by("sample_index").to_pylist()
        for shard in dict.fromkeys(r["shard"] for r in rows):
            wanted = {member_names(r["key"], self.image_ext)[1]: r for r in rows if r["shard"] == shard}
            found = 0
            for name, data in stream_members(shard_path(self.path, shard), set(wanted)):
                found += 1
                yield wanted[name]["key"], decode_image(data, self.image_ext, f"{shard}: {name}"), wanted[name]
            if found < len(wanted):
                raise AppdgenError(f"{self.path}: {len(wanted) - found} samples of {INDEX} not found in {shard} "
                                   f"(run appdgen verify)")


def open_build(path: str | Path) -> Build:
    """A finished build folder; AppdgenError naming the folder when it is missing, unfinished or not a build."""
    out = Path(path)
    check_finished(out)
    try:
        info = read_info(out)
        entries = tuple(_entry(out, s) for s in info.get("shards", []))
        return Build(out, info, reference_of(info), image_ext(info), entries)
    except AppdgenError as exc:
        raise AppdgenError(f"{out}: {exc}") from None


def _entry(out: Path, listed: object) -> ShardEntry:
    """A shard entry of build.json's `shards` list."""
    if not isinstance(listed, dict) or not isinstance(listed.get("file"), str):
        raise AppdgenError(f"{BUILD_JSON}: shards list holds {listed!r}, not a shard entry")
    splits = listed.get("splits") or {}
    return ShardEntry(shard_path(out, listed["file"]), int(listed.get("samples", 0)), dict(splits))
