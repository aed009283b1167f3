"""Tiny stand-in shards in appdgen's output layout, with a learnable label, for tests and benchmarks."""
from __future__ import annotations

import io
import json
from pathlib import Path

import cv2
import numpy as np
import webdataset as wds

INTRINSICS = {"fx": 100.0, "fy": 100.0, "cx": 64.0, "cy": 64.0, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}


def texture(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """A smooth random colour texture, H×W×3 float in [0, 1] (a stand-in for a raw camera image)."""
    small = rng.random((max(2, h // 16), max(2, w // 16), 3)).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 1)


def encode(img: np.ndarray, fmt: str) -> bytes:
    """PNG/JPEG bytes via OpenCV, or .npy bytes of the uint8 array."""
    if fmt == "npy":
        buf = io.BytesIO()
        np.save(buf, img)
        return buf.getvalue()
    ok, data = cv2.imencode(f".{fmt}", img)
    assert ok
    return data.tobytes()


def sample_image(base: np.ndarray, gain: float) -> np.ndarray:
    """The raw texture darkened by gain: brightness carries the label."""
    return (base * gain * 255).round().astype(np.uint8)


def write_shards(
    out: str | Path,
    n: int = 64,
    size: tuple[int, int] = (128, 128),
    per_shard: int = 16,
    splits: tuple[tuple[str, int], ...] = (("train", 3), ("test", 1)),
    fmt: str = "png",
    appd_max: float = 3.0,
    per_raw: int = 4,
    seed: int = 0,
) -> Path:
    """Write n samples as OUT/shard-*.tar + labels.parquet + build.json; label = appd_max·(gain−0.2)/0.8.

    Samples come in groups of per_raw sharing one raw texture (a 'raw image'); raw images cycle
    through `splits` by weight, so a split never shares raw images with another.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    w, h = size
    cycle = [name for name, weight in splits for _ in range(weight)]
    rows: list[dict] = []
    shards: list[dict] = []
    base = texture(rng, w, h)
    for i in range(n):
        if i % per_raw == 0:
            base = texture(rng, w, h)
        raw = i // per_raw
        gain = float(rng.uniform(0.2, 1.0))
        meta = {
            "key": f"{i:09d}", "sample_index": i, "split": cycle[raw % len(cycle)],
            "appd_pct": appd_max * (gain - 0.2) / 0.8, "is_reference": False,
            "width": w, "height": h, "raw_path": f"raw/rec{raw % 3}/{raw:06d}.png", **INTRINSICS,
        }
        meta["appd_px"] = meta["appd_pct"] / 100 * float(np.hypot(w, h))
        if i % per_shard == 0:
            shards.append({"file": f"shard-{len(shards):06d}.tar", "samples": 0, "splits": {}})
            writer = wds.TarWriter(str(out / shards[-1]["file"]))
        writer.write({"__key__": meta["key"], fmt: encode(sample_image(base, gain), fmt), "json": meta})
        entry = shards[-1]
        entry["samples"] += 1
        entry["splits"][meta["split"]] = entry["splits"].get(meta["split"], 0) + 1
        rows.append({**meta, "shard": entry["file"], "camera": "00"})
        if i % per_shard == per_shard - 1 or i == n - 1:
            writer.close()
    _write_labels(out, rows)
    _write_build(out, rows, shards, size, fmt, appd_max, seed)
    return out


def _write_labels(out: Path, rows: list[dict]) -> None:
    """OUT/labels.parquet with the columns the trainer reads."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = ["key", "shard", "raw_path", "split", "camera", "sample_index", "is_reference", "appd_px", "appd_pct"]
    pq.write_table(pa.table({c: [r[c] for r in rows] for c in cols}), out / "labels.parquet")


def _write_build(out: Path, rows: list[dict], shards: list[dict], size: tuple[int, int], fmt: str,
                 appd_max: float, seed: int) -> None:
    """OUT/build.json with counts per split and per shard."""
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["split"]] = counts.get(r["split"], 0) + 1
    build = {
        "appdgen_version": "synthetic", "seed": seed, "size": list(size), "format": fmt, "appd_max": appd_max,
        "counts": {"samples": len(rows), "splits": counts}, "shards": shards,
    }
    (out / "build.json").write_text(json.dumps(build, indent=1))
