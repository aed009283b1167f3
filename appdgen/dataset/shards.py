"""The writer of a build folder: deterministic WebDataset tar shards, their Parquet label fragments, the index and
build.json, each written atomically, all named by appdgen.dataset.layout (appdgen.dataset.reader reads them back).

BuildWriter is the one interface: a worker streams a shard's samples into `shard(k)`; the parent marks the shard
done with `shard_done` (its fragment, written last); `finish` writes labels.parquet and build.json and drops the
parts. The build, resume and the trainer's synthetic stand-in shards all write through it.
"""
from __future__ import annotations

import hashlib
import io
import json
import secrets
import shutil
import tarfile
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

from appdgen.dataset.layout import (
    BUILD_JSON,
    HASH_COLUMN,
    INDEX,
    PARTS_DIR,
    STATS_KEY,
    ShardStats,
    fragment_name,
    label_schema,
    member_names,
    record_json,
    shard_name,
)
from appdgen.util.atomic import atomic_stream, atomic_write

if TYPE_CHECKING:
    import pyarrow as pa


def _arrow():
    """pyarrow and pyarrow.parquet, imported where a table is written or read (the parent), not in the workers that
    only stream tars (~80 ms of each worker's start)."""
    import pyarrow
    import pyarrow.parquet

    return pyarrow, pyarrow.parquet


class TarShard:
    """Streams `<key>.<ext>` members into a shard tar that appears (atomically) when the block ends cleanly."""

    def __init__(self, path: Path) -> None:
        self.path, self.size = path, 0
        self._stack = ExitStack()

    def __enter__(self) -> "TarShard":
        self._stream = self._stack.enter_context(atomic_stream(self.path))
        # USTAR with zeroed times/owners: the same samples always give the same bytes.
        # One copy per member (tarfile's default copies a 1 MB image in 64 chunks of 16 KB).
        self._tar = tarfile.open(fileobj=self._stream, mode="w", format=tarfile.USTAR_FORMAT, copybufsize=1 << 24)
        return self

    def add(self, name: str, data: bytes) -> None:
        """Append one regular-file member."""
        info = tarfile.TarInfo(name)
        info.size, info.mtime, info.mode = len(data), 0, 0o644
        info.uid = info.gid = 0
        info.uname = info.gname = ""
        self._tar.addfile(info, io.BytesIO(data))

    def add_sample(self, row: dict, ext: str, data: bytes) -> None:
        """Append one sample: its label record (`<key>.json`), then its encoded image (`<key><ext>`); sets the
        row's image hash."""
        record, image = member_names(row["key"], ext)
        self.add(record, record_json(row))
        row[HASH_COLUMN] = hashlib.sha256(data).hexdigest()
        self.add(image, data)

    def __exit__(self, *exc_info) -> None:
        if exc_info[0] is None:
            self._tar.close()
            self.size = self._stream.tell()
        self._stack.__exit__(*exc_info)


def write_fragment(path: Path, rows: list[dict], params: Sequence[str], stats: ShardStats,
                   sources: bool = False) -> pa.Table:
    """One shard's label rows (columns of label_schema(params, sources)) and its stats as a Parquet file,
    atomically; returns the table written (the index can take it from memory)."""
    pa, _ = _arrow()
    schema = label_schema(params, sources)
    columns = [pa.array([r[n] for r in rows], f.type) for n, f in zip(schema.names, schema, strict=True)]
    table = pa.Table.from_arrays(columns, schema=schema.with_metadata({STATS_KEY: stats.to_json()}))
    _write_table(path, table)
    return table


def read_stats(fragment: Path | pa.Table) -> ShardStats:
    """The ShardStats stored with a shard's fragment: its file, or the table write_fragment returned."""
    pa, pq = _arrow()
    schema = fragment.schema if isinstance(fragment, pa.Table) else pq.read_schema(fragment)
    return ShardStats.from_json(schema.metadata[STATS_KEY])


def read_fragment(path: Path, schema: pa.Schema) -> pa.Table:
    """One shard's label rows, read with their schema."""
    return _arrow()[1].read_table(path, schema=schema)


def write_index(path: Path, fragments: list[Path | pa.Table], params: Sequence[str], sources: bool = False) -> int:
    """Concatenate shard fragments (files, or tables write_fragment returned) in order into labels.parquet,
    atomically; returns the row count."""
    pa, _ = _arrow()
    schema = label_schema(params, sources)
    tables = [f.cast(schema) if isinstance(f, pa.Table) else read_fragment(f, schema) for f in fragments]
    table = pa.concat_tables(tables) if tables else schema.empty_table()
    _write_table(path, table)
    return table.num_rows


def _write_table(path: Path, table: pa.Table) -> None:
    """A Parquet file (zstd, no timestamps: same rows, same bytes), written atomically."""
    pa, pq = _arrow()
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd")
    atomic_write(path, sink.getvalue().to_pybytes())


class BuildWriter:
    """Writes one build folder `out`: shard tars, their fragments under .parts (a shard is done once its fragment
    is), then labels.parquet and build.json; `params` are the lens model's parameter columns, `sources` adds the
    recordings' columns (layout.SOURCE_COLUMNS)."""

    def __init__(self, out: Path, params: Sequence[str], sources: bool = False) -> None:
        self.out, self.params, self.sources = Path(out), tuple(params), sources
        self.parts = self.out / PARTS_DIR

    def shard(self, shard: int) -> TarShard:
        """The tar of shard `shard`, to fill in a `with` block (it appears when the block ends cleanly)."""
        return TarShard(self.out / shard_name(shard))

    def is_done(self, shard: int) -> bool:
        """Whether a shard's fragment (written last) and tar are both there."""
        return (self.parts / fragment_name(shard)).is_file() and (self.out / shard_name(shard)).is_file()

    def shard_done(self, stats: ShardStats, rows: list[dict]) -> pa.Table:
        """Write a finished shard's label rows and stats as its fragment (marking it done); returns the table."""
        self.parts.mkdir(parents=True, exist_ok=True)
        return write_fragment(self.parts / fragment_name(stats.shard), rows, self.params, stats, self.sources)

    def finish(self, shard_count: int, made: dict[int, pa.Table], summary: Callable[[list[ShardStats]], dict]) -> dict:
        """Write labels.parquet from the fragments (this run's from memory, `made`) and build.json from
        summary(stats of every shard), then drop the parts; returns build.json's content."""
        fragments = [made.get(k, self.parts / fragment_name(k)) for k in range(shard_count)]
        write_index(self.out / INDEX, fragments, self.params, self.sources)
        content = summary([read_stats(f) for f in fragments])
        atomic_write(self.out / BUILD_JSON, json.dumps(content, indent=2).encode())
        # One rename ends the build (a kill during a plain rmtree could leave a plan-less, unresumable .parts).
        trash = self.out / f".{PARTS_DIR}.{secrets.token_hex(4)}.tmp"
        self.parts.rename(trash)
        shutil.rmtree(trash)
        return content
