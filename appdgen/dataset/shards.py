"""Writers: deterministic WebDataset tar shards and their Parquet label fragments, each written atomically."""
from __future__ import annotations

import io
import tarfile
from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from appdgen.util.atomic import atomic_stream, atomic_write
from appdgen.dataset.layout import STATS_KEY, ShardStats, label_schema


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

    def __exit__(self, *exc_info) -> None:
        if exc_info[0] is None:
            self._tar.close()
            self.size = self._stream.tell()
        self._stack.__exit__(*exc_info)


def write_fragment(path: Path, rows: list[dict], params: Sequence[str], stats: ShardStats,
                   sources: bool = False) -> pa.Table:
    """One shard's label rows (columns of label_schema(params, sources)) and its stats as a Parquet file,
    atomically; returns the table written (the index can take it from memory)."""
    schema = label_schema(params, sources)
    columns = [pa.array([r[n] for r in rows], f.type) for n, f in zip(schema.names, schema)]
    table = pa.Table.from_arrays(columns, schema=schema.with_metadata({STATS_KEY: stats.to_json()}))
    _write_table(path, table)
    return table


def read_stats(fragment: Path | pa.Table) -> ShardStats:
    """The ShardStats stored with a shard's fragment: its file, or the table write_fragment returned."""
    schema = fragment.schema if isinstance(fragment, pa.Table) else pq.read_schema(fragment)
    return ShardStats.from_json(schema.metadata[STATS_KEY])


def read_fragment(path: Path, schema: pa.Schema) -> pa.Table:
    """One shard's label rows, read with their schema."""
    return pq.read_table(path, schema=schema)


def write_index(path: Path, fragments: list[Path | pa.Table], params: Sequence[str], sources: bool = False) -> int:
    """Concatenate shard fragments (files, or tables write_fragment returned) in order into labels.parquet,
    atomically; returns the row count."""
    schema = label_schema(params, sources)
    tables = [f.cast(schema) if isinstance(f, pa.Table) else read_fragment(f, schema) for f in fragments]
    table = pa.concat_tables(tables) if tables else schema.empty_table()
    _write_table(path, table)
    return table.num_rows


def _write_table(path: Path, table: pa.Table) -> None:
    """A Parquet file (zstd, no timestamps: same rows, same bytes), written atomically."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd")
    atomic_write(path, sink.getvalue().to_pybytes())
