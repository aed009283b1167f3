"""A build's folder over its life: --out checked against --resume/--overwrite and the plan recorded (never
deleting what is not ours), what a killed build left cleaned up, and the shards still to build on a resume."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from appdgen.dataset.layout import (
    BEND_COLUMNS,
    CROP_COLUMNS,
    INDEX,
    OUTPUT_NAMES,
    PARTS_DIR,
    PLAN,
    SHARD_FILE,
    fragment_name,
)
from appdgen.dataset.plan import BuildConfig, plan_content
from appdgen.dataset.shards import BuildWriter, read_stats
from appdgen.dataset.worker import warp_columns
from appdgen.errors import AppdgenError
from appdgen.geometry.crop import Crop
from appdgen.util.atomic import atomic_write, temporary_target


def recorded_encoder(out: Path) -> str | None:
    """The --encoder the interrupted build in `out` writes (its plan's: opencv for plans from before --encoder), or
    None where no plan can be read (prepare_out then says why)."""
    try:
        return plan_content(json.loads((out / PARTS_DIR / PLAN).read_text()))["encoder"]
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None


def prepare_out(out: Path, config: BuildConfig, resume: bool, overwrite: bool) -> BuildConfig:
    """Check --out against --resume/--overwrite and record the plan; never deletes what is not ours.

    Returns the config to build with: on --resume, with the names the interrupted build recorded (its content
    may have been given from another working folder or through another relative path).
    """
    if out.exists() and not out.is_dir():
        raise AppdgenError(f"--out {out}: exists and is not a folder")
    plan_path = out / PARTS_DIR / PLAN
    existing = [] if _unplanned_leftovers(out) else sorted(out.iterdir())
    if existing and resume:
        if not plan_path.is_file():
            if (out / INDEX).is_file():
                _remove_temporaries(out)  # a kill between the end's rename of .parts and its removal leaves it
                raise AppdgenError(f"--out {out}: the build there is already complete (use --overwrite to redo it)")
            raise AppdgenError(f"--out {out}: not an interrupted appdgen build (no {PARTS_DIR}/{PLAN})")
        record = json.loads(plan_path.read_text())
        recorded = plan_content(record)["encoder"]
        if config.image_format == "png" and recorded not in (None, config.encoder):
            raise AppdgenError(f"{plan_path}: the interrupted build writes --encoder {recorded}, not "
                               f"{config.encoder}; resume it with --encoder {recorded}, or use --overwrite")
        if plan_content(record) != config.plan():
            raise AppdgenError(f"--out {out}: the interrupted build used other inputs or options (or a calibration "
                               f"file or image set that changed since); rerun it with the same ones, or use "
                               f"--overwrite")
        _remove_temporaries(out)
        return config.renamed(record)
    if existing and not overwrite:
        raise AppdgenError(f"--out {out}: folder is not empty (use --resume to finish an interrupted build, "
                           f"--overwrite to replace it)")
    try:
        if existing:
            _remove_outputs(out)
        (out / PARTS_DIR).mkdir(parents=True, exist_ok=True)
        _remove_temporaries(out)
        atomic_write(plan_path, json.dumps(config.record(), indent=1).encode())
    except OSError as exc:
        raise AppdgenError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
    return config


def _is_ours(name: str) -> bool:
    """Whether a name in --out is one a build writes (shards, index, build.json, parts) or a temporary of one."""
    name = temporary_target(name) or name
    return bool(SHARD_FILE.fullmatch(name)) or name in OUTPUT_NAMES


def _unplanned_leftovers(out: Path) -> bool:
    """Whether --out holds at most what a build killed before writing its plan leaves (.parts, temporaries)."""
    if not out.is_dir():
        return True
    parts = out / PARTS_DIR
    if (parts / PLAN).exists():
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


def add_bend_columns(config: BuildConfig, writer: BuildWriter, done: list[int]) -> None:
    """Give the fragments of done shards that a build from before BEND_COLUMNS wrote their bend columns, from each
    row's own parameters and crop (what a worker computes from the draw), so that the index has one schema."""
    import pyarrow.parquet as pq  # here: the parent resumes, workers never import pyarrow

    reference_crop = config.sampler().reference_rect.crop
    for shard in done:
        path = writer.parts / fragment_name(shard)
        if set(BEND_COLUMNS) <= set(pq.read_schema(path).names):
            continue
        table = pq.read_table(path)
        rows = table.to_pylist()
        for row in rows:
            calib = config.reference.replace(**{name: row[name] for name in config.reference.param_names})
            crop = Crop(*(row[name] for name in CROP_COLUMNS))
            row.update(warp_columns(config.reference, reference_crop, calib, crop))
        writer.shard_done(read_stats(table), rows)


def pending_shards(out: Path, config: BuildConfig) -> list[int]:
    """Shards whose fragment (written last) or tar is missing."""
    writer = config.writer(out)
    return [k for k in range(config.shard_count) if not writer.is_done(k)]
