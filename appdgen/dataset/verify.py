"""`appdgen verify`: every shard of a finished build re-read member by member and checked against labels.parquet
and build.json.

The checks trust nothing in OUT; a problem is reported as 'file: member: problem' and the scan goes on to find the
others.
"""
from __future__ import annotations

import hashlib
import json
import re
import tarfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import BinaryIO

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from appdgen.dataset.encoders import ENCODERS, LEGACY_ENCODER
from appdgen.dataset.layout import (
    BUILD_JSON,
    HASH_COLUMN,
    INDEX,
    RECORD_EXT,
    SHARD_GLOB,
    member_names,
    member_record,
    record_json,
    sample_key,
    shard_name,
)
from appdgen.dataset.reader import check_finished, counts, image_ext, read_index, read_info, shard_path
from appdgen.errors import AppdgenError

BLOCK = tarfile.BLOCKSIZE  # 512: tar headers and data are padded to blocks
RECORD = tarfile.RECORDSIZE  # 10240: tarfile (like GNU tar) pads the archive to whole 20-block records
KEPT_PROBLEMS = 1000  # problems kept word for word; the rest are only counted
CHECKSUM_FIELD = re.compile(rb"[0-7]{6}\0 ")  # as tarfile (and GNU tar) write it; the sum itself skips these bytes




@dataclass
class Report:
    """What verify found: counts checked and problems as 'file: member: problem' lines."""

    samples: int = 0
    shard_count: int = 0
    problems: list[str] = field(default_factory=list)
    total: int = 0  # problems found; only the first KEPT_PROBLEMS are kept as text
    notes: list[str] = field(default_factory=list)  # what could not be checked here, and why (not problems)

    def add(self, where: str, problem: str) -> None:
        """Record one problem at 'file' or 'file: member'."""
        self.total += 1
        if len(self.problems) < KEPT_PROBLEMS:
            self.problems.append(f"{where}: {problem}")

    @property
    def ok(self) -> bool:
        """True when nothing was found wrong."""
        return self.total == 0


def verify(out: Path) -> Report:
    """Re-read every shard of a finished build and check it against labels.parquet and build.json."""
    check_finished(out)
    report = Report()
    try:
        info = read_info(out)
        table, ext = read_index(out, info), image_ext(info)
    except AppdgenError as error:  # a damaged index or summary is a finding, not a usage error
        where, _, problem = str(error).partition(": ")
        report.add(where, problem)
        return report
    report.samples = table.num_rows
    empty = {name: table[name].null_count for name in table.column_names if table[name].null_count}
    if empty:  # rows with holes cannot be matched to members
        report.add(INDEX, "empty values in " + ", ".join(f"{name} ({n})" for name, n in empty.items()))
        return report
    shards = list(counts(table["shard"]))
    report.shard_count = len(shards)
    _verify_index(table, info, report)
    _verify_info(out, table, info, report)
    encoder = _recorded_encoder(info, ext, report)
    for name in shards:
        try:
            path = shard_path(out, name)
        except AppdgenError as error:
            report.add(INDEX, str(error).partition(": ")[2])
            continue
        rows = table.filter(pc.equal(table["shard"], name)).sort_by("sample_index").to_pylist()
        _verify_shard(path, rows, ext, report)
        if encoder is not None and rows:
            _verify_encoding(path, rows[0], ext, encoder, report)
    for path in sorted(out.glob(SHARD_GLOB)):
        if path.name not in shards:
            report.add(path.name, f"shard file not named in {INDEX}")
    return report


def _verify_index(table: pa.Table, info: dict, report: Report) -> None:
    """labels.parquet on its own: unique keys, key = sample index, indices 0…N−1, shard = index ÷ shard size."""
    shard_size = info.get("shard_size") or 1
    indices = table["sample_index"].to_pylist()
    for key, n in counts(table["key"]).items():
        if n > 1:
            report.add(INDEX, f"key {key} appears in {n} rows")
    for key, index, shard in zip(table["key"].to_pylist(), indices, table["shard"].to_pylist(), strict=True):
        if key != sample_key(index):
            report.add(INDEX, f"row with key {key} has sample_index {index}")
        elif shard != shard_name(index // shard_size):
            report.add(INDEX, f"sample {key} is listed in {shard}, its shard is {shard_name(index // shard_size)}")
    if sorted(indices) != list(range(len(indices))):
        report.add(INDEX, f"sample indices are not 0…{len(indices) - 1}")


def _verify_info(out: Path, table: pa.Table, info: dict, report: Report) -> None:
    """build.json's counts and shard list against the index and the files."""
    stated, listed = info["counts"], {s.get("file"): s for s in info.get("shards", []) if isinstance(s, dict)}
    shard_rows = counts(table["shard"])
    expected = {
        "samples": (stated.get("samples"), table.num_rows),
        "shards": (stated.get("shards"), len(shard_rows)),
        "references": (stated.get("references"), pc.sum(table["is_reference"]).as_py() or 0),
        "splits": (stated.get("splits"), counts(table["split"])),
    }
    for name, (claim, actual) in expected.items():
        if claim != actual:
            report.add(BUILD_JSON, f"counts.{name} is {claim}, {INDEX} has {actual}")
    if len(listed) != len(info.get("shards", [])) or set(listed) != set(shard_rows):
        report.add(BUILD_JSON, f"shards list names {len(listed)} files, {INDEX} {len(shard_rows)}")
    for name, stats in sorted(listed.items()):
        path = out / str(name)
        if name in shard_rows and stats.get("samples") != shard_rows[name]:
            report.add(BUILD_JSON, f"{name}: {stats.get('samples')} samples, {INDEX} has {shard_rows[name]}")
        if path.is_file() and stats.get("bytes") != path.stat().st_size:
            report.add(BUILD_JSON, f"{name}: {stats.get('bytes')} bytes, the file has {path.stat().st_size}")


def _recorded_encoder(info: dict, ext: str, report: Report) -> str | None:
    """The PNG encoder build.json records (builds before --encoder: opencv), when it can be re-run here; else None,
    with a problem (an unknown name) or a note (its package is not installed)."""
    if ext != ".png":
        return None
    name = info.get("encoder", LEGACY_ENCODER)
    if name not in ENCODERS:
        report.add(BUILD_JSON, f"encoder {name!r} is not one of {', '.join(ENCODERS)}")
        return None
    encoder = ENCODERS[name]
    if not encoder.available():
        report.notes.append(f"encoder {name} is not installed here ({encoder.package}): the images' encoding is "
                            f"unchecked (their sha256 is)")
        return None
    library = encoder.library
    recorded = (info.get("libraries") or {}).get(library)
    if recorded != encoder.version():  # another version may write other bytes for the same pixels
        report.notes.append(f"{BUILD_JSON} records {library} {recorded}, this machine has {encoder.version()}: the "
                            f"images' encoding is unchecked (their sha256 is)")
        return None
    return name


def _verify_encoding(path: Path, row: dict, ext: str, encoder: str, report: Report) -> None:
    """A shard's first image decodes as PNG and encodes back to the same bytes with the recorded encoder (so the
    bytes are that encoder's, and a rebuild anywhere gives them again)."""
    name = member_names(row["key"], ext)[1]
    try:
        with tarfile.open(path, mode="r:") as tar:
            data = tar.extractfile(name).read()
    except (OSError, tarfile.TarError, KeyError, AttributeError):
        return  # the shard scan has reported it
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        report.add(f"{path.name}: {name}", "not a readable PNG")
    elif ENCODERS[encoder].encode(image) != data:
        report.add(f"{path.name}: {name}", f"not the bytes --encoder {encoder} writes for its pixels ({BUILD_JSON} "
                                           f"records {encoder})")


def _verify_shard(path: Path, rows: list[dict], ext: str, report: Report) -> None:
    """One shard against its index rows: names, order, types, bytes of every member, and the tar's end."""
    if not path.is_file():
        report.add(path.name, f"missing ({len(rows)} samples of {INDEX} are in it)")
        return
    expected = {name: r for r in rows for name in member_names(r["key"], ext)}
    seen: dict[str, None] = {}  # members checked so far, in order (a dict: order and fast lookup)
    try:
        with path.open("rb") as raw, tarfile.open(fileobj=raw, mode="r:") as tar:
            end = _scan_members(path, raw, tar, expected, seen, report)
            _verify_end(path, raw, end, seen, report)
    except (OSError, tarfile.TarError) as exc:
        report.add(f"{path.name}: {_next_name(expected, seen)}", f"unreadable tar ({exc})")
    _verify_found(path, expected, seen, report)


def _scan_members(path: Path, raw: BinaryIO, tar: tarfile.TarFile, expected: dict[str, dict],
                  seen: dict[str, None], report: Report) -> int:
    """Check each member in turn; returns the byte offset where the last member's data (padded) ends."""
    size, end = path.stat().st_size, 0
    for member in tar:
        where = f"{path.name}: {member.name}"
        problem = _member_problem(member, expected, seen)
        if member.name in expected:
            seen[member.name] = None  # found, even if broken: it gets one line, not a second 'missing'
        if member.offset_data + member.size > size:
            report.add(where, f"truncated: data ends at byte {member.offset_data + member.size}, file has {size}")
            return -1
        end = member.offset_data + -(-member.size // BLOCK) * BLOCK
        problem = problem or _block_problem(raw, member)
        if problem is None:
            problem = _content_problem(member.name, tar.extractfile(member).read(), expected[member.name])
        if problem:
            report.add(where, problem)
    return end


def _member_problem(member: tarfile.TarInfo, expected: dict[str, dict], seen: dict[str, None]) -> str | None:
    """What is wrong with a member's header: unsafe name, not a plain file, not expected here, or repeated."""
    name = PurePosixPath(member.name)
    if name.is_absolute() or ".." in name.parts or "\\" in member.name:
        return "unsafe name (absolute or with '..')"
    if member.issym() or member.islnk():
        kind = "symbolic" if member.issym() else "hard"
        return f"{kind} link to {member.linkname!r}: only plain files belong in a shard"
    if not member.isreg():
        return f"not a plain file (tar type {member.type!r})"
    if member.offset_data != member.offset + BLOCK:
        return "extended (pax/GNU) header: appdgen writes plain USTAR headers only"
    if member.name not in expected:
        return f"unexpected member (not a sample of this shard in {INDEX})"
    if member.name in seen:
        return "duplicate member"
    return None


def _block_problem(raw: BinaryIO, member: tarfile.TarInfo) -> str | None:
    """What tarfile overlooks: the checksum field's exact form (outside the sum) and the padding after the data."""
    raw.seek(member.offset)
    field_bytes = raw.read(BLOCK)[148:156]
    if not CHECKSUM_FIELD.fullmatch(field_bytes):
        return f"damaged header: checksum field {field_bytes!r}"
    padding = -member.size % BLOCK
    raw.seek(member.offset_data + member.size)
    return None if raw.read(padding).count(0) == padding else "non-zero bytes in the padding after its data"


def _content_problem(name: str, data: bytes, row: dict) -> str | None:
    """An image member's sha256, or a JSON member's fields and bytes, against its index row."""
    if not name.endswith(RECORD_EXT):
        return None if hashlib.sha256(data).hexdigest() == row[HASH_COLUMN] else f"sha256 differs from {INDEX}"
    try:
        record = json.loads(data)
    except (UnicodeDecodeError, ValueError) as exc:
        return f"not valid JSON ({exc})"
    want = member_record(row)
    if not isinstance(record, dict):
        return "JSON is not an object"
    if set(record) != set(want):
        odd = sorted(set(record) ^ set(want))
        return f"fields differ from {INDEX}'s columns ({', '.join(odd[:3])}{', …' if len(odd) > 3 else ''})"
    for key in ("key", "appd_pct", *sorted(want)):
        if record[key] != want[key]:
            return f"{key} is {record[key]!r} here, {want[key]!r} in {INDEX}"
    return None if data == record_json(row) else f"bytes differ from its {INDEX} row written as JSON"


def _verify_end(path: Path, raw: BinaryIO, end: int, seen: dict[str, None], report: Report) -> None:
    """After the last member: two zero blocks, zero padding to a whole record, nothing else."""
    if end < 0:
        return
    size = path.stat().st_size
    where = f"{path.name}: after {next(reversed(seen), 'the start')}"
    if size < end + 2 * BLOCK:
        report.add(where, f"truncated: {size} bytes, the end-of-archive blocks need {end + 2 * BLOCK}")
        return
    raw.seek(end)
    offset = end
    while chunk := raw.read(1 << 20):
        if chunk.count(0) != len(chunk):
            report.add(where, f"non-zero bytes at {offset + len(chunk) - len(chunk.lstrip(bytes(1)))} after the "
                              f"last readable member (a damaged header, or data past the end of the archive)")
            return
        offset += len(chunk)
    if size % RECORD:
        report.add(where, f"{size} bytes is not a whole number of {RECORD}-byte tar records (truncated?)")


def _verify_found(path: Path, expected: dict[str, dict], seen: dict[str, None], report: Report) -> None:
    """Every expected member found, in index order (key.json, then the image, per sample)."""
    missing = [name for name in expected if name not in seen]
    for name in missing[:3]:
        report.add(f"{path.name}: {name}", "missing")
    if len(missing) > 3:
        report.add(path.name, f"{len(missing) - 3} more members missing")
    order = [name for name in expected if name in seen]
    if not missing and list(seen) != order:
        first = next(a for a, b in zip(seen, order, strict=False) if a != b)
        report.add(f"{path.name}: {first}", "out of order (expected key.json then the image, by sample index)")


def _next_name(expected: dict[str, dict], seen: dict[str, None]) -> str:
    """The first expected member not yet seen: where a scan that broke off stopped."""
    return next((name for name in expected if name not in seen), "end")
