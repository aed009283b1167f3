"""Writers: deterministic WebDataset tar shards and their Parquet label fragments, each written atomically."""
from __future__ import annotations

import io
import json
import tarfile
from contextlib import ExitStack
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from appdgen.atomic import atomic_stream, atomic_write

SHARD_PATTERN = "shard-{:06d}.tar"
PARTS_DIR = ".parts"

#: labels.parquet columns: units in the names or below (pixels, % of the raw diagonal).
LABEL_SCHEMA = pa.schema([
    ("key", pa.string()), ("shard", pa.string()), ("raw_path", pa.string()), ("split", pa.string()),
    ("camera", pa.string()), ("sample_index", pa.int64()), ("is_reference", pa.bool_()),
    ("fx", pa.float64()), ("fy", pa.float64()), ("cx", pa.float64()), ("cy", pa.float64()),
    ("k1", pa.float64()), ("k2", pa.float64()), ("p1", pa.float64()), ("p2", pa.float64()), ("k3", pa.float64()),
    ("new_fx", pa.float64()), ("new_fy", pa.float64()), ("new_cx", pa.float64()), ("new_cy", pa.float64()),
    ("width", pa.int32()), ("height", pa.int32()), ("appd_px", pa.float64()), ("appd_pct", pa.float64()),
    ("sha256", pa.string()),
])


def shard_name(index: int) -> str:
    """File name of shard `index`."""
    return SHARD_PATTERN.format(index)


def sample_key(index: int) -> str:
    """WebDataset key of sample `index` (sorts in sample order)."""
    return f"{index:09d}"


class TarShard:
    """Streams `<key>.<ext>` members into a shard tar that appears (atomically) when the block ends cleanly."""

    def __init__(self, path: Path) -> None:
        self.path, self.size = path, 0
        self._stack = ExitStack()

    def __enter__(self) -> "TarShard":
        self._stream = self._stack.enter_context(atomic_stream(self.path))
        # USTAR with zeroed times/owners: the same samples always give the same bytes.
        self._tar = tarfile.open(fileobj=self._stream, mode="w", format=tarfile.USTAR_FORMAT)
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


def record_json(record: dict) -> bytes:
    """A sample's `<key>.json` member: its label row, keys sorted, floats in full precision."""
    return json.dumps(record, sort_keys=True, separators=(",", ":")).encode("utf-8")


def write_fragment(path: Path, rows: list[dict]) -> None:
    """One shard's label rows as a Parquet file, atomically."""
    _write_table(path, pa.Table.from_pylist(rows, schema=LABEL_SCHEMA))


def read_fragment(path: Path) -> pa.Table:
    """One shard's label rows."""
    return pq.read_table(path, schema=LABEL_SCHEMA)


def write_index(path: Path, fragments: list[Path]) -> int:
    """Concatenate shard fragments in order into labels.parquet, atomically; returns the row count."""
    table = pa.concat_tables([read_fragment(f) for f in fragments]) if fragments else LABEL_SCHEMA.empty_table()
    _write_table(path, table)
    return table.num_rows


def _write_table(path: Path, table: pa.Table) -> None:
    """A Parquet file (zstd, no timestamps: same rows, same bytes), written atomically."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, compression="zstd")
    atomic_write(path, sink.getvalue().to_pybytes())
