"""Reading a finished build back: a text summary, a contact sheet of samples, and a full check of shards vs index.

The checks trust nothing in OUT: every shard is re-read member by member and compared with labels.parquet and
build.json; a problem is reported as 'file: member: problem' and the scan goes on to find the others.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import tarfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import BinaryIO

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from appdgen import lens
from appdgen.calib.calibration import DEFAULT_MODEL, INTRINSICS
from appdgen.errors import AppdgenError
from appdgen.dataset.images import decode_image
from appdgen.dataset.layout import (BUILD_JSON, FORMATS, FRAGMENT_GLOB, HASH_COLUMN, INDEX, PARTS_DIR, PLAN, SHARD_FILE,
                            SHARD_GLOB, label_schema, member_record, record_json, sample_key, shard_name)

BLOCK = tarfile.BLOCKSIZE  # 512: tar headers and data are padded to blocks
RECORD = tarfile.RECORDSIZE  # 10240: tarfile (like GNU tar) pads the archive to whole 20-block records
KEPT_PROBLEMS = 1000  # problems kept word for word; the rest are only counted
CHECKSUM_FIELD = re.compile(rb"[0-7]{6}\0 ")  # as tarfile (and GNU tar) write it; the sum itself skips these bytes


# --- reading a build -----------------------------------------------------------------------------------------


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


def open_build(out: Path) -> tuple[pa.Table, dict]:
    """A finished build's labels.parquet and build.json; AppdgenError when missing, unfinished or unreadable."""
    check_finished(out)
    info = read_info(out)
    return read_index(out, info), info


def model_params(info: dict) -> tuple[str, ...]:
    """The label columns' parameter names of a build, from the lens model build.json records."""
    calibration = info.get("calibration")
    model = calibration.get("model", DEFAULT_MODEL) if isinstance(calibration, dict) else DEFAULT_MODEL
    try:
        return (*INTRINSICS, *lens.params(str(model)))
    except AppdgenError as exc:
        raise AppdgenError(f"{BUILD_JSON}: {exc}") from None


def read_index(out: Path, info: dict) -> pa.Table:
    """labels.parquet with the label schema of build.json's lens model; AppdgenError naming the file otherwise."""
    schema = label_schema(model_params(info))
    try:
        table = pq.read_table(out / INDEX)
    except (OSError, pa.ArrowException) as exc:
        raise AppdgenError(f"{INDEX}: unreadable ({exc})") from None
    if not (table.schema.equals(schema) or table.schema.equals(label_schema(model_params(info), crop=False))):
        missing = [n for n in schema.names if n not in table.schema.names]
        raise AppdgenError(f"{INDEX}: columns differ from appdgen's label schema"
                           + (f" (missing {', '.join(missing)})" if missing else ""))
    return table


def read_info(out: Path) -> dict:
    """build.json as a dict; AppdgenError naming the file when unreadable."""
    try:
        info = json.loads((out / BUILD_JSON).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise AppdgenError(f"{BUILD_JSON}: unreadable ({getattr(exc, 'strerror', None) or exc})") from None
    if not isinstance(info, dict) or not isinstance(info.get("counts"), dict):
        raise AppdgenError(f"{BUILD_JSON}: not an appdgen build summary (no counts)")
    return info


def image_ext(info: dict) -> str:
    """The image members' extension ('.png', '.jpg', '.npy') from build.json's format."""
    ext = FORMATS.get(info.get("format"))
    if ext is None:
        raise AppdgenError(f"{BUILD_JSON}: format {info.get('format')!r} is not one of {', '.join(FORMATS)}")
    return ext


def counts(column: pa.ChunkedArray) -> dict[str, int]:
    """How often each value occurs in a column, sorted by value."""
    return dict(sorted((c["values"].as_py(), c["counts"].as_py()) for c in pc.value_counts(column)))


def shard_path(out: Path, name: str) -> Path:
    """The path of a shard named in the index; never a path the index made up (e.g. '../x')."""
    if not SHARD_FILE.fullmatch(name):
        raise AppdgenError(f"{INDEX}: shard {name!r} is not a shard file name")
    return out / name


def read_members(path: Path, names: set[str]) -> dict[str, bytes]:
    """The bytes of some members of a tar shard, by name (members not found are left out)."""
    found = {}
    try:
        with tarfile.open(path, mode="r:") as tar:
            for member in tar:
                if member.name in names and member.isreg():
                    found[member.name] = tar.extractfile(member).read()
    except (OSError, tarfile.TarError) as exc:
        raise AppdgenError(f"{path}: unreadable shard ({exc})") from None
    return found


# --- inspect: text summary -----------------------------------------------------------------------------------


def summary(out: Path, bins: int = 10) -> str:
    """A text summary of a finished build: counts, splits, APPD labels and histogram, speed, size on disk."""
    table, info = open_build(out)
    calib = info.get("calibration", {})
    diagonal = math.hypot(calib.get("width", 0), calib.get("height", 0))
    pct, px = table["appd_pct"].to_numpy(), table["appd_px"].to_numpy()
    size = "x".join(str(v) for v in info.get("size", []))
    skipped = len(info["counts"].get("skipped_images") or [])
    lines = [
        f"{out}: {table.num_rows} samples in {len(counts(table['shard']))} shards, {size} {info.get('format')}, "
        f"from {len(counts(table['raw_path']))} raw images" + (f" ({skipped} skipped)" if skipped else "")
        + f" (camera {calib.get('camera')}, {calib.get('model', DEFAULT_MODEL)} lens, of {calib.get('path')})"
        + (f", crops bounded at {info['max_fov']:g}° (--max-fov)" if info.get("max_fov") is not None else ""),
        "splits: " + ", ".join(f"{name} {n}" for name, n in counts(table["split"]).items()),
        f"reference samples (exactly the calibration, APPD 0): {pc.sum(table['is_reference']).as_py() or 0}",
        _label_line(pct, px, diagonal),
        *histogram(pct, float(info.get("appd_max") or (pct.max() if pct.size else 1.0)), bins),
        *_speed_lines(info),
        _disk_line(out),
    ]
    return "\n".join(lines)


def _label_line(pct: np.ndarray, px: np.ndarray, diagonal: float) -> str:
    """'APPD labels: min–max (mean) in % of the diagonal and in raw pixels'."""
    if not pct.size:
        return "APPD labels: none"
    return (f"APPD labels: {pct.min():.3f}–{pct.max():.3f} % (mean {pct.mean():.3f} %) of the {diagonal:.1f} px "
            f"raw diagonal = {px.min():.2f}–{px.max():.2f} px (mean {px.mean():.2f} px)")


def histogram(values: np.ndarray, top: float, bins: int = 10, width: int = 40) -> list[str]:
    """Text histogram of APPD % over [0, top] in `bins` bins (values above `top` fall in the last bin)."""
    top = top if top > 0 else 1.0
    counts = np.bincount(np.clip((values / top * bins).astype(int), 0, bins - 1), minlength=bins)
    scale = width / max(counts.max(), 1)
    above = int((values > top).sum())
    lines = [f"APPD histogram, % of the diagonal, {bins} bins over [0, {top:g}]"
             + (f" ({above} above {top:g} counted in the last bin)" if above else "") + ":"]
    for i, count in enumerate(counts):
        bar = "#" * int(round(count * scale))
        lines.append(f"  {i * top / bins:5.3f}–{(i + 1) * top / bins:5.3f}  {bar:<{width}} {count}")
    return lines


def _speed_lines(info: dict) -> list[str]:
    """Sampler efficiency and throughput from build.json."""
    sampler, timings = info.get("sampler", {}), info.get("timings", {})
    rate = timings.get("samples_per_second")
    return [
        f"sampler: {sampler.get('evaluations_per_sample', 0):.2f} APPD evaluations and "
        f"{1000 * sampler.get('seconds_per_sample', 0):.1f} ms per drawn sample",
        f"throughput: {rate or 0:.1f} samples/s ({timings.get('wall_seconds', 0):.1f} s wall; "
        f"{timings.get('shards_built', 0)} shards built, {timings.get('shards_resumed', 0)} resumed)",
        *_stage_line(timings.get("stage_seconds") or {}),
    ]


def _stage_line(stages: dict[str, float]) -> list[str]:
    """Where the workers' time went, in % per stage (none for a build that built nothing now)."""
    total = sum(stages.values())
    if total <= 0:
        return []
    return ["worker time: " + ", ".join(f"{name} {100 * seconds / total:.1f} %" for name, seconds in stages.items())]


def _disk_line(out: Path) -> str:
    """Bytes on disk of the shards, the index and build.json, in MB (10⁶ bytes)."""
    shards = sum(p.stat().st_size for p in out.glob(SHARD_GLOB))
    index, info = (out / INDEX).stat().st_size, (out / BUILD_JSON).stat().st_size
    return (f"on disk: {(shards + index + info) / 1e6:.1f} MB (shards {shards / 1e6:.1f} MB, "
            f"{INDEX} {index / 1e6:.2f} MB, {BUILD_JSON} {info / 1e6:.3f} MB)")


# --- inspect: contact sheet ----------------------------------------------------------------------------------

TILE_WIDTH = (288, 464)  # px: narrower samples are enlarged, wider ones shrunk, so captions stay readable
CAPTION = 22  # px: text strip under each tile
HEADER = 26  # px: title strip at the top of the sheet
GAP = 4  # px between tiles
SHEET_ASPECT = 4 / 3  # width : height the grid aims for, like a screen
FONT, FONT_SCALE = cv2.FONT_HERSHEY_SIMPLEX, 0.45


def spread(pct: np.ndarray, count: int) -> np.ndarray:
    """Row numbers of `count` samples at evenly spaced APPD ranks, lowest to highest (deterministic)."""
    order = np.lexsort((np.arange(pct.size), pct))  # ties broken by row, so the choice never varies
    if count >= pct.size:
        return order
    return order[np.round(np.linspace(0, pct.size - 1, count)).astype(int)]


def sheet_layout(count: int, width: int, height: int) -> tuple[int, int, int, int]:
    """(columns, rows, tile width, tile height) in px for `count` samples of width×height: a grid about 4:3 wide."""
    tile_w = min(max(width, TILE_WIDTH[0]), TILE_WIDTH[1])
    tile_h = max(1, round(height * tile_w / width))
    columns = max(1, min(count, round(math.sqrt(count * SHEET_ASPECT * (tile_h + CAPTION) / tile_w))))
    return columns, -(-count // columns), tile_w, tile_h


def contact_sheet(out: Path, count: int = 24) -> np.ndarray:
    """A BGR image: `count` samples spread over the APPD range in a grid, each captioned with APPD and key."""
    if count < 1:
        raise AppdgenError(f"--count {count}: must be at least 1")
    table, info = open_build(out)
    ext = image_ext(info)
    if not table.num_rows:
        raise AppdgenError(f"{out}: {INDEX} has no samples")
    rows = table.take(pa.array(spread(table["appd_pct"].to_numpy(), count))).to_pylist()
    images = _sample_images(out, rows, ext)
    columns, lines, tile_w, tile_h = sheet_layout(len(rows), rows[0]["width"], rows[0]["height"])
    sheet = np.full((HEADER + lines * (tile_h + CAPTION + GAP) + GAP, columns * (tile_w + GAP) + GAP, 3), 32,
                    np.uint8)
    title = (f"{out.name}: {len(rows)} of {table.num_rows} samples, evenly spaced by APPD "
             f"(% of the raw diagonal | raw px, then key)")
    _text(sheet, title, (GAP, HEADER - 9), columns * (tile_w + GAP) - GAP, (255, 255, 255))
    for i, row in enumerate(rows):
        y = HEADER + GAP + (i // columns) * (tile_h + CAPTION + GAP)
        x = GAP + (i % columns) * (tile_w + GAP)
        tile = cv2.resize(_as_bgr(images[row["key"]]), (tile_w, tile_h), interpolation=cv2.INTER_AREA)
        sheet[y:y + tile_h, x:x + tile_w] = tile
        _caption(sheet, x, y + tile_h, tile_w, row)
    return sheet


def _sample_images(out: Path, rows: list[dict], ext: str) -> dict[str, np.ndarray]:
    """Decoded images of the chosen rows, by key, reading each shard once."""
    images: dict[str, np.ndarray] = {}
    for shard in sorted({r["shard"] for r in rows}):
        names = {f"{r['key']}{ext}" for r in rows if r["shard"] == shard}
        for name, data in read_members(shard_path(out, shard), names).items():
            images[name[: -len(ext)]] = decode_image(data, ext, f"{shard}: {name}")
    missing = [r["key"] for r in rows if r["key"] not in images]
    if missing:
        raise AppdgenError(f"{out}: sample {missing[0]} not found in its shard (run appdgen verify)")
    return images


def _as_bgr(image: np.ndarray) -> np.ndarray:
    """An 8-bit 3-channel view of a decoded sample (grey images are repeated over the channels)."""
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image[..., :3]


def _caption(sheet: np.ndarray, x: int, y: int, width: int, row: dict) -> None:
    """Write 'APPD % | px' on the left and the key on the right of the strip under a tile."""
    left = f"{row['appd_pct']:.3f} % | {row['appd_px']:.2f} px" + (" (ref)" if row["is_reference"] else "")
    key_width = cv2.getTextSize(row["key"], FONT, FONT_SCALE, 1)[0][0]
    _text(sheet, left, (x + 2, y + CAPTION - 7), width - key_width - 12, (255, 255, 255))
    _text(sheet, row["key"], (x + width - key_width - 2, y + CAPTION - 7), key_width, (160, 200, 255))


def _text(sheet: np.ndarray, text: str, origin: tuple[int, int], room: int, colour: tuple[int, int, int]) -> None:
    """Anti-aliased text at `origin` (baseline, px), shrunk to fit `room` px rather than overlap."""
    width = cv2.getTextSize(text, FONT, FONT_SCALE, 1)[0][0]
    scale = FONT_SCALE * min(1.0, max(room, 1) / width)
    cv2.putText(sheet, text, origin, FONT, scale, colour, 1, cv2.LINE_AA)


# --- verify ----------------------------------------------------------------------------------------------------


@dataclass
class Report:
    """What verify found: counts checked and problems as 'file: member: problem' lines."""

    samples: int = 0
    shards: int = 0
    problems: list[str] = field(default_factory=list)
    total: int = 0  # problems found; only the first KEPT_PROBLEMS are kept as text

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
    report.shards = len(shards)
    _check_index(table, info, report)
    _check_info(out, table, info, report)
    for name in shards:
        try:
            path = shard_path(out, name)
        except AppdgenError as error:
            report.add(INDEX, str(error).partition(": ")[2])
            continue
        rows = table.filter(pc.equal(table["shard"], name)).sort_by("sample_index").to_pylist()
        _check_shard(path, rows, ext, report)
    for path in sorted(out.glob(SHARD_GLOB)):
        if path.name not in shards:
            report.add(path.name, f"shard file not named in {INDEX}")
    return report


def _check_index(table: pa.Table, info: dict, report: Report) -> None:
    """labels.parquet on its own: unique keys, key = sample index, indices 0…N−1, shard = index ÷ shard size."""
    shard_size = info.get("shard_size") or 1
    indices = table["sample_index"].to_pylist()
    for key, n in counts(table["key"]).items():
        if n > 1:
            report.add(INDEX, f"key {key} appears in {n} rows")
    for key, index, shard in zip(table["key"].to_pylist(), indices, table["shard"].to_pylist()):
        if key != sample_key(index):
            report.add(INDEX, f"row with key {key} has sample_index {index}")
        elif shard != shard_name(index // shard_size):
            report.add(INDEX, f"sample {key} is listed in {shard}, its shard is {shard_name(index // shard_size)}")
    if sorted(indices) != list(range(len(indices))):
        report.add(INDEX, f"sample indices are not 0…{len(indices) - 1}")


def _check_info(out: Path, table: pa.Table, info: dict, report: Report) -> None:
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


def _check_shard(path: Path, rows: list[dict], ext: str, report: Report) -> None:
    """One shard against its index rows: names, order, types, bytes of every member, and the tar's end."""
    if not path.is_file():
        report.add(path.name, f"missing ({len(rows)} samples of {INDEX} are in it)")
        return
    expected = {f"{r['key']}{suffix}": r for r in rows for suffix in (".json", ext)}
    seen: dict[str, None] = {}  # members checked so far, in order (a dict: order and fast lookup)
    try:
        with path.open("rb") as raw, tarfile.open(fileobj=raw, mode="r:") as tar:
            end = _scan_members(path, raw, tar, expected, seen, report)
            _check_end(path, raw, end, seen, report)
    except (OSError, tarfile.TarError) as exc:
        report.add(f"{path.name}: {_next_name(expected, seen)}", f"unreadable tar ({exc})")
    _check_found(path, expected, seen, report)


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
    if not name.endswith(".json"):
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


def _check_end(path: Path, raw: BinaryIO, end: int, seen: dict[str, None], report: Report) -> None:
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


def _check_found(path: Path, expected: dict[str, dict], seen: dict[str, None], report: Report) -> None:
    """Every expected member found, in index order (key.json, then the image, per sample)."""
    missing = [name for name in expected if name not in seen]
    for name in missing[:3]:
        report.add(f"{path.name}: {name}", "missing")
    if len(missing) > 3:
        report.add(path.name, f"{len(missing) - 3} more members missing")
    order = [name for name in expected if name in seen]
    if not missing and list(seen) != order:
        first = next(a for a, b in zip(seen, order) if a != b)
        report.add(f"{path.name}: {first}", "out of order (expected key.json then the image, by sample index)")


def _next_name(expected: dict[str, dict], seen: dict[str, None]) -> str:
    """The first expected member not yet seen: where a scan that broke off stopped."""
    return next((name for name in expected if name not in seen), "end")
