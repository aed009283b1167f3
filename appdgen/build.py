"""The generator: sample → rectify → label → shard, in parallel, deterministic and resumable.

Shard k holds samples [k·S, (k+1)·S). A worker builds a whole shard: the tar is written atomically, then its
stats and its Parquet fragment under `.parts/` (the fragment marks the shard done). Resume skips done shards;
the index and build.json are written once every shard is done. Bytes depend on the inputs, options and seed
only, never on --jobs or on scheduling.
"""
from __future__ import annotations

import hashlib
import json
import platform
import secrets
import shutil
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from appdgen import __version__
from appdgen.appd import appd_px, px_to_pct
from appdgen.atomic import atomic_write, temporary_target
from appdgen.calibration import Calibration
from appdgen.crop import check_output_size, valid_region
from appdgen.distribute import check_parallel, run_unordered
from appdgen.errors import AppdgenError
from appdgen.images import encode_image, read_image
from appdgen.maps import rectify
from appdgen.progress import Progress
from appdgen.render import remap_image
from appdgen.sampling import DEFAULT_APPD_MAX, Range, Sampler, paper_ranges
from appdgen.shards import PARTS_DIR, record_json, sample_key, shard_name, TarShard, write_fragment, write_index
from appdgen.sources import RawImage

FORMATS = {"png": ".png", "jpg": ".jpg", "npy": ".npy"}
OUTPUT_NAMES = ("labels.parquet", "build.json", PARTS_DIR)


@dataclass(frozen=True)
class BuildConfig:
    """Everything that decides a build's bytes (inputs, options, seed)."""

    reference: Calibration
    camera: str
    calib_path: str
    images: tuple[RawImage, ...]
    samples: int
    size: tuple[int, int]
    image_format: str = "png"
    shard_size: int = 1000
    seed: int = 0
    ranges: dict[str, Range] = field(default_factory=paper_ranges)
    appd_max: float = DEFAULT_APPD_MAX
    zero_fraction: float = 0.01
    interp: str = "lanczos4"

    def __post_init__(self) -> None:
        if self.samples < 1:
            raise AppdgenError(f"--samples {self.samples}: must be at least 1")
        if self.shard_size < 1:
            raise AppdgenError(f"--shard-size {self.shard_size}: must be at least 1")
        if self.image_format not in FORMATS:
            raise AppdgenError(f"--format {self.image_format!r}: expected one of {', '.join(FORMATS)}")
        if not self.images:
            raise AppdgenError("no raw images given")
        try:
            object.__setattr__(self, "size", check_output_size(self.reference, self.size))
        except AppdgenError as exc:
            raise AppdgenError(f"--size: {exc}") from None
        self._check_reference()
        # Refuses bad --appd-max, --zero-fraction and --ranges now, before --out is touched, not in a worker.
        Sampler(self.reference, self.ranges, self.appd_max, self.zero_fraction, self.size)

    def _check_reference(self) -> None:
        """Refuse a reference without a valid crop (e.g. a folding lens), naming its file."""
        try:
            valid_region(self.reference)
        except AppdgenError as exc:
            raise AppdgenError(f"{self.calib_path}: camera {self.camera}: {exc}") from None

    @property
    def shards(self) -> int:
        """Number of shards."""
        return -(-self.samples // self.shard_size)

    def shard_samples(self, shard: int) -> range:
        """Sample indices of one shard."""
        return range(shard * self.shard_size, min((shard + 1) * self.shard_size, self.samples))

    def image_for(self, index: int) -> RawImage:
        """The raw image of sample `index`: consecutive blocks per image, so a shard decodes few images."""
        return self.images[index * len(self.images) // self.samples]

    def plan(self) -> dict:
        """A JSON-ready description of everything that shapes the output, to check a resume against."""
        return {
            "appdgen_version": __version__,
            "calibration": {"path": self.calib_path, "camera": self.camera, **self.reference.to_dict()},
            "images": [[i.name, i.split] for i in self.images],
            "samples": self.samples, "size": list(self.size), "format": self.image_format,
            "shard_size": self.shard_size, "seed": self.seed, "appd_max": self.appd_max,
            "zero_fraction": self.zero_fraction, "interp": self.interp,
            "ranges": {name: r.describe() for name, r in self.ranges.items()},
        }


def build_shard(job: tuple[BuildConfig, str, int]) -> dict:
    """Build one shard (tar + stats + fragment) in a worker; returns its stats."""
    config, out_dir, shard = job
    cv2.setNumThreads(1)  # the parent decides parallelism
    out = Path(out_dir)
    start = time.perf_counter()
    sampler = Sampler(config.reference, config.ranges, config.appd_max, config.zero_fraction, config.size)
    reference = rectify(config.reference, config.size)
    ext = FORMATS[config.image_format]
    rows, evaluations, sampler_seconds = [], 0, 0.0
    cache: tuple[Path, np.ndarray] | None = None
    # Streamed to disk as it grows: a 1,000-sample full-size shard would be ~1 GB in memory.
    with TarShard(out / shard_name(shard)) as tar:
        for index in config.shard_samples(shard):
            draw = sampler.draw(config.seed, index)
            evaluations, sampler_seconds = evaluations + draw.evaluations, sampler_seconds + draw.seconds
            rect = reference if draw.is_reference else rectify(draw.calib, config.size)
            raw_image = config.image_for(index)
            if cache is None or cache[0] != raw_image.path:
                cache = (raw_image.path, read_image(raw_image.path))
            data = encode_image(remap_image(cache[1], rect, config.interp), ext)
            row = _label_row(config, shard, index, raw_image, draw.is_reference, rect, appd_px(reference, rect))
            tar.add(f"{row['key']}.json", record_json(row))
            row["sha256"] = hashlib.sha256(data).hexdigest()
            tar.add(f"{row['key']}{ext}", data)
            rows.append(row)
    size = tar.size
    stats = {"shard": shard, "file": shard_name(shard), "samples": len(rows), "bytes": size,
             "splits": dict(sorted(Counter(r["split"] for r in rows).items())),
             "references": sum(r["is_reference"] for r in rows), "evaluations": evaluations,
             "sampler_seconds": sampler_seconds, "seconds": time.perf_counter() - start}
    parts = out / PARTS_DIR
    atomic_write(parts / f"{shard_name(shard)}.stats.json", json.dumps(stats).encode())
    write_fragment(parts / f"{shard_name(shard)}.parquet", rows)
    return stats


def _label_row(config: BuildConfig, shard: int, index: int, image: RawImage, is_reference: bool, rect,
               distance_px: float) -> dict:
    """One sample's label: perturbed Θ, K̂ of its crop, output size and APPD (px and % of the diagonal)."""
    k = rect.new_camera_matrix
    return {
        "key": sample_key(index), "shard": shard_name(shard), "raw_path": image.name, "split": image.split,
        "camera": config.camera, "sample_index": index, "is_reference": bool(is_reference),
        **rect.calib.params(),
        "new_fx": float(k[0, 0]), "new_fy": float(k[1, 1]), "new_cx": float(k[0, 2]), "new_cy": float(k[1, 2]),
        "width": config.size[0], "height": config.size[1],
        "appd_px": distance_px, "appd_pct": px_to_pct(distance_px, config.reference),
    }


def prepare_out(out: Path, config: BuildConfig, resume: bool, overwrite: bool) -> None:
    """Check --out against --resume/--overwrite and record the plan; never deletes what is not ours."""
    if out.exists() and not out.is_dir():
        raise AppdgenError(f"--out {out}: exists and is not a folder")
    plan_path = out / PARTS_DIR / "plan.json"
    existing = [] if _unplanned_leftovers(out) else sorted(out.iterdir())
    if existing and resume:
        if not plan_path.is_file():
            if (out / "labels.parquet").is_file():
                raise AppdgenError(f"--out {out}: the build there is already complete (use --overwrite to redo it)")
            raise AppdgenError(f"--out {out}: not an interrupted appdgen build (no {PARTS_DIR}/plan.json)")
        if json.loads(plan_path.read_text()) != config.plan():
            raise AppdgenError(f"--out {out}: the interrupted build used other inputs or options; "
                               f"rerun it with the same ones, or use --overwrite")
        _remove_temporaries(out)
        return
    if existing and not overwrite:
        raise AppdgenError(f"--out {out}: folder is not empty (use --resume to finish an interrupted build, "
                           f"--overwrite to replace it)")
    try:
        if existing:
            _remove_outputs(out)
        (out / PARTS_DIR).mkdir(parents=True, exist_ok=True)
        _remove_temporaries(out)
        atomic_write(plan_path, json.dumps(config.plan(), indent=1).encode())
    except OSError as exc:
        raise AppdgenError(f"--out {out}: cannot write ({exc.strerror or exc})") from None


def _is_ours(name: str) -> bool:
    """Whether a name in --out is one a build writes (shards, index, build.json, parts) or a temporary of one."""
    name = temporary_target(name) or name
    return name.startswith("shard-") or name in OUTPUT_NAMES


def _unplanned_leftovers(out: Path) -> bool:
    """Whether --out holds at most what a build killed before writing its plan leaves (.parts, temporaries)."""
    if not out.is_dir():
        return True
    parts = out / PARTS_DIR
    if (parts / "plan.json").exists():
        return False
    outside = all(p.name == PARTS_DIR or (temporary_target(p.name) and _is_ours(p.name)) for p in out.iterdir())
    return outside and all(temporary_target(p.name) for p in (parts.iterdir() if parts.is_dir() else ()))


def _remove_temporaries(out: Path) -> None:
    """Delete the temporaries a killed build left in --out and .parts (their files get written anew)."""
    parts = out / PARTS_DIR
    ours = [p for p in out.iterdir() if temporary_target(p.name) and _is_ours(p.name)]
    ours += [p for p in (parts.iterdir() if parts.is_dir() else ()) if temporary_target(p.name)]
    for path in ours:
        shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)


def _remove_outputs(out: Path) -> None:
    """Remove a previous build's files (shards, index, build.json, parts) and nothing else."""
    foreign = [p.name for p in out.iterdir() if not _is_ours(p.name)]
    if foreign:
        raise AppdgenError(f"--out {out}: --overwrite refuses a folder holding other files too ({foreign[0]}, …)")
    for path in out.iterdir():
        shutil.rmtree(path) if path.is_dir() else path.unlink()


def pending_shards(out: Path, config: BuildConfig) -> list[int]:
    """Shards whose fragment (written last) or tar is missing."""
    parts = out / PARTS_DIR
    return [k for k in range(config.shards)
            if not ((parts / f"{shard_name(k)}.parquet").is_file() and (out / shard_name(k)).is_file())]


def build(config: BuildConfig, out: Path, jobs: int = 1, backend: str = "loky", scheduler: str | None = None,
          resume: bool = False, overwrite: bool = False, progress: bool = True, command: list[str] | None = None,
          skipped: list[str] | None = None) -> dict:
    """Run a build into `out` and return build.json's content."""
    start = time.perf_counter()
    check_parallel(jobs, backend)
    prepare_out(out, config, resume, overwrite)
    todo = pending_shards(out, config)
    bar = Progress(config.samples, enabled=progress)
    bar.advance(config.samples - sum(len(config.shard_samples(k)) for k in todo), "resumed" if resume else "")
    try:
        for stats in run_unordered(build_shard, [(config, str(out), k) for k in todo], jobs, backend, scheduler):
            bar.advance(stats["samples"], stats["file"])
        return _finish(config, out, todo, start, command, skipped or [])
    except OSError as exc:
        raise AppdgenError(f"--out {out}: write failed ({exc.strerror or exc}); fix it and rerun with --resume") from None
    except AppdgenError as exc:
        raise AppdgenError(f"{exc} (finished shards are kept: fix this and rerun with --resume)") from None


def _finish(config: BuildConfig, out: Path, built: list[int], start: float, command: list[str] | None,
            skipped: list[str]) -> dict:
    """Write labels.parquet and build.json from the parts, then drop the parts; returns build.json's content."""
    parts = out / PARTS_DIR
    shards = [json.loads((parts / f"{shard_name(k)}.stats.json").read_text()) for k in range(config.shards)]
    write_index(out / "labels.parquet", [parts / f"{shard_name(k)}.parquet" for k in range(config.shards)])
    summary = _summary(config, shards, built, time.perf_counter() - start, command, skipped)
    atomic_write(out / "build.json", json.dumps(summary, indent=2).encode())
    # One rename ends the build (a kill during a plain rmtree could leave a plan-less, unresumable .parts).
    trash = out / f".{PARTS_DIR}.{secrets.token_hex(4)}.tmp"
    parts.rename(trash)
    shutil.rmtree(trash)
    return summary


def _summary(config: BuildConfig, shards: list[dict], built: list[int], seconds: float, command: list[str] | None,
             skipped: list[str]) -> dict:
    """build.json: what was asked, what was written, how fast, with which libraries."""
    splits: Counter = Counter()
    for stats in shards:
        splits.update(stats["splits"])
    made = [s for s in shards if s["shard"] in set(built)]
    drawn = sum(s["samples"] - s["references"] for s in shards)
    written_mb = sum(s["bytes"] for s in made) / 1e6
    return {
        **config.plan(),
        "command": command or sys.argv,
        "counts": {"samples": config.samples, "shards": config.shards, "splits": dict(sorted(splits.items())),
                   "references": sum(s["references"] for s in shards), "images": len(config.images),
                   "skipped_images": skipped},
        "shards": [{k: s[k] for k in ("file", "samples", "bytes", "splits")} for s in shards],
        "sampler": {"evaluations_per_sample": sum(s["evaluations"] for s in shards) / max(drawn, 1),
                    "seconds_per_sample": sum(s["sampler_seconds"] for s in shards) / max(drawn, 1)},
        "timings": {"wall_seconds": seconds, "shards_built": len(made), "shards_resumed": config.shards - len(made),
                    "samples_per_second": sum(s["samples"] for s in made) / seconds if seconds > 0 else None,
                    "mb_written": written_mb},
        "libraries": _versions(),
    }


def _versions() -> dict:
    """Versions of Python and the libraries that shape the bytes."""
    import joblib
    import pyarrow

    return {"python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
            "pyarrow": pyarrow.__version__, "joblib": joblib.__version__}
