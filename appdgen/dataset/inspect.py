"""`appdgen inspect`: a finished build as a text summary (counts, splits, APPD labels, speed, size on disk) and as
a contact sheet of samples spread over the APPD range."""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from appdgen.calib.calibration import DEFAULT_MODEL
from appdgen.dataset.images import decode_image
from appdgen.dataset.layout import BEND_LABEL, BUILD_JSON, INDEX, SHARD_GLOB, member_names
from appdgen.dataset.reader import counts, open_build, read_members, shard_path
from appdgen.errors import AppdgenError


def summary(out: Path, bins: int = 10) -> str:
    """A text summary of a finished build: counts, splits, APPD labels and histogram, speed, size on disk."""
    build = open_build(out)
    table, info = build.labels(), build.info
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
        *_bend_line(table, pct),
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


def _bend_line(table: pa.Table, pct: np.ndarray) -> list[str]:
    """'bend (the non-affine part): min–max (mean) in % of the diagonal, its share of APPD', for builds with it."""
    if BEND_LABEL not in table.column_names or not pct.size:
        return []
    bend = table[BEND_LABEL].to_numpy()
    return [f"bend (the non-affine part of APPD): {bend.min():.3f}–{bend.max():.3f} % (mean {bend.mean():.3f} %), "
            f"{bend.sum() / max(pct.sum(), 1e-12):.0%} of APPD in all"]


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
    build = open_build(out)
    table, ext = build.labels(), build.image_ext
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
        names = {member_names(r["key"], ext)[1] for r in rows if r["shard"] == shard}
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
