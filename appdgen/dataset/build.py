"""The generator: sample → rectify → label → shard, in parallel, deterministic and resumable.

Shard k holds samples [k·S, (k+1)·S). A worker builds a whole shard's tar (written atomically); the parent then
writes its label rows and stats as a Parquet fragment under `.parts/` (the fragment marks the shard done). Resume skips done shards;
the index and build.json are written once every shard is done. Bytes depend on the inputs, options and seed
only, never on --jobs or on scheduling. File names come from appdgen.dataset.layout.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import platform
import shutil
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from appdgen.version import __version__
from appdgen.geometry.appd import px_to_pct
from appdgen.util.atomic import atomic_write, temporary_target
from appdgen.calib.calibration import Calibration
from appdgen.geometry.bend import split_warp
from appdgen.geometry.crop import Crop, check_max_fov, check_output_size, valid_region
from appdgen.util.distribute import check_parallel, run_unordered
from appdgen.errors import AppdgenError
from appdgen.sources.decode import as_channels, read_image
from appdgen.dataset.encoders import DEFAULT_ENCODER, LEGACY_ENCODER, get_encoder
from appdgen.dataset.images import encode_image
from appdgen.dataset.layout import (FORMATS, INDEX, OUTPUT_NAMES, PARTS_DIR, PLAN, SHARD_FILE, STAGES, ShardStats,
                                    BEND_COLUMNS, CROP_COLUMNS, bend_columns, crop_columns, fragment_name,
                                    sample_key, shard_name, source_columns)
from appdgen.geometry.maps import Rectification
from appdgen.util.progress import Progress
from appdgen.geometry.remap import DEFAULT_INTERP, remap_image
from appdgen.sampling.ranges import Range, default_ranges
from appdgen.sampling.reach import UnreachableError
from appdgen.sampling.options import DEFAULT_ZERO_FRACTION, SamplingOptions
from appdgen.sampling.sampler import DEFAULT_APPD_MAX, Sampler
from appdgen.dataset.shards import BuildWriter, read_stats
from appdgen.sources.frames import Frame, RawImage
from appdgen.sources.headers import check_complete

if TYPE_CHECKING:  # workers never import pyarrow (~80 ms of each one's start): the parent writes the fragments
    import pyarrow as pa

MAX_SHARD_SIZE = 1000  # default samples per shard of large builds
MIN_SHARD_SIZE = 8  # … and about the least of small ones
SHARDS_PER_BUILD = 64  # a small build is cut into at most this many shards, so every worker gets work


def default_shard_size(samples: int) -> int:
    """--shard-size when not given, from --samples alone: N/8 shards but at most 64, rounded down to a multiple
    of 4 so that 2 or 4 workers (3 or 6 often) share them evenly; at most 1,000 samples a shard."""
    shards = min(SHARDS_PER_BUILD, samples // MIN_SHARD_SIZE)
    shards = shards // 4 * 4 or max(shards, 1)
    return min(MAX_SHARD_SIZE, -(-samples // shards))


def content_hash(parts: list[str]) -> str:
    """SHA-256 of text lines (hex): what a plan records instead of names that depend on the working folder."""
    return hashlib.sha256("\n".join(parts).encode("utf-8", "surrogateescape")).hexdigest()


def file_hash(path: str) -> str | None:
    """SHA-256 of a file's bytes (hex), or None when it is not a readable file."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


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
    shard_size: int | None = None  # default_shard_size(samples)
    seed: int = 0
    ranges: dict[str, Range] | None = None  # default_ranges(reference)
    appd_max: float = DEFAULT_APPD_MAX
    zero_fraction: float = DEFAULT_ZERO_FRACTION
    interp: str = DEFAULT_INTERP
    max_fov: float | None = None  # degrees: bounds the horizontal field of view of every crop
    channels: int = 3  # of the samples: 1 grey, 3 BGR
    recordings: tuple[tuple[str, str], ...] = ()  # (source, sha256) of the recordings the frames come from
    encoder: str = DEFAULT_ENCODER  # of PNG samples: a name in encoders.ENCODERS
    #: plan(), when already known: a config renamed after a plan.json has the same content, so the same plan.
    known_plan: dict | None = field(default=None, compare=False, repr=False)

    @property
    def from_recordings(self) -> bool:
        """Whether the raw images are frames of recordings (bags, videos): labels get the source columns."""
        return bool(self.recordings)

    def __post_init__(self) -> None:
        if self.samples < 1:
            raise AppdgenError(f"--samples {self.samples}: must be at least 1")
        if self.shard_size is None:
            object.__setattr__(self, "shard_size", default_shard_size(self.samples))
        if self.shard_size < 1:
            raise AppdgenError(f"--shard-size {self.shard_size}: must be at least 1")
        if self.image_format not in FORMATS:
            raise AppdgenError(f"--format {self.image_format!r}: expected one of {', '.join(FORMATS)}")
        if not self.images:
            raise AppdgenError("no raw images given")
        if self.ranges is None:
            object.__setattr__(self, "ranges", default_ranges(self.reference))
        try:
            object.__setattr__(self, "size", check_output_size(self.reference, self.size))
        except AppdgenError as exc:
            raise AppdgenError(f"--size: {exc}") from None
        check_max_fov(self.max_fov)
        if self.channels not in (1, 3):
            raise AppdgenError(f"--channels {self.channels}: expected 1 or 3")
        if self.image_format == "png":
            get_encoder(self.encoder, self.channels)
        elif self.encoder != DEFAULT_ENCODER:
            raise AppdgenError(f"--encoder {self.encoder}: encodes --format png only, not {self.image_format}")
        self._check_reference()

    def _check_reference(self) -> None:
        """Refuse a reference without a valid crop (e.g. a folding lens), naming its file."""
        try:
            valid_region(self.reference, max_fov=self.max_fov)
        except AppdgenError as exc:
            raise AppdgenError(f"{self.calib_path}: camera {self.camera}: {exc}") from None

    @property
    def shard_count(self) -> int:
        """Number of shards."""
        return -(-self.samples // self.shard_size)

    @property
    def ext(self) -> str:
        """The image members' extension."""
        return FORMATS[self.image_format]

    def writer(self, out: Path) -> BuildWriter:
        """The writer of this build's folder `out` (its label columns follow the lens model and the source)."""
        return BuildWriter(out, self.reference.param_names, self.from_recordings)

    def shard_samples(self, shard: int) -> range:
        """Sample indices of one shard."""
        return range(shard * self.shard_size, min((shard + 1) * self.shard_size, self.samples))

    def image_for(self, index: int) -> RawImage:
        """The raw image of sample `index`: consecutive blocks per image, so a shard decodes few images."""
        return self.images[index * len(self.images) // self.samples]

    @property
    def sampling(self) -> SamplingOptions:
        """The build's sampling options (the type `fit --online` shares)."""
        return SamplingOptions(tuple(sorted(self.ranges.items())), self.appd_max, self.zero_fraction, self.max_fov,
                               self.interp)

    def sampler(self) -> Sampler:
        """The build's labelling sampler (set up once per process and build options)."""
        return self.sampling.sampler(self.reference, self.size)

    def plan(self) -> dict:
        """A JSON-ready description of everything that shapes the output, by content: the calibration file's
        hash and the images' resolved paths (not the names they were given by), to check a resume against."""
        return self.known_plan if self.known_plan is not None else self._plan

    @functools.cached_property
    def _plan(self) -> dict:
        """plan(), worked out once per config: it reads the calibration file and resolves every image path."""
        recordings = {"recordings_sha256": [h for _, h in self.recordings]} if self.recordings else {}
        return {
            "appdgen_version": __version__,
            "calibration": {"camera": self.camera, "sha256": file_hash(self.calib_path), **self.reference.to_dict()},
            "images_sha256": content_hash([_image_line(i) for i in self.images]), **recordings,
            "channels": self.channels,
            "samples": self.samples, "size": list(self.size), "format": self.image_format,
            "encoder": self.encoder if self.image_format == "png" else None,
            "shard_size": self.shard_size, "seed": self.seed, "appd_max": self.appd_max,
            "zero_fraction": self.zero_fraction, "interp": self.interp, "max_fov": self.max_fov,
            "ranges": {name: r.describe() for name, r in self.ranges.items()},
        }

    def record(self) -> dict:
        """plan() plus the names as given (calibration path, image names and splits): plan.json and build.json."""
        plan = self.plan()
        sources = {"recordings": [s for s, _ in self.recordings]} if self.recordings else {}
        return {**plan, "calibration": {"path": self.calib_path, **plan["calibration"]}, **sources,
                "images": [[i.name, i.split] for i in self.images]}

    def renamed(self, record: dict) -> "BuildConfig":
        """This config with the names a plan.json recorded (same content, so the resumed rows match the rest)."""
        sources = dict(zip((s for s, _ in self.recordings), record.get("recordings", ())))
        images = tuple(dataclasses.replace(i, name=name, split=split, frame=i.frame and dataclasses.replace(
                           i.frame, source=sources.get(i.frame.source, i.frame.source)))
                       for i, (name, split) in zip(self.images, record["images"]))
        recordings = tuple((sources.get(s, s), h) for s, h in self.recordings)
        return dataclasses.replace(self, calib_path=record["calibration"]["path"], images=images,
                                   recordings=recordings, known_plan=self.plan())


def _image_line(image: RawImage) -> str:
    """A raw image in the plan's images hash: its resolved path and split, for a frame also its place."""
    line = f"{image.path.resolve()}\t{image.split}"
    frame = image.frame
    return line if frame is None else f"{line}\t{frame.topic}\t{frame.timestamp_ns}\t{frame.repeat}\t{frame.pts}"


def plan_content(record: dict) -> dict:
    """The plan inside a recorded plan.json: without the names, which may differ for the same content."""
    content = {k: v for k, v in record.items() if k not in ("images", "recordings")}
    # Plans from before --encoder name none (their PNG is OpenCV's); jpg and npy samples have no PNG encoder, though
    # plans of the first --encoder version recorded the default for them too.
    content.setdefault("encoder", LEGACY_ENCODER)
    if content.get("format", "png") != "png":
        content["encoder"] = None
    calibration = record.get("calibration")
    if isinstance(calibration, dict):
        content["calibration"] = {k: v for k, v in calibration.items() if k != "path"}
    return content


def build_shard(job: tuple[BuildConfig, str, int]) -> tuple[ShardStats, list[dict]]:
    """Build one shard's tar in a worker; returns its stats and label rows (the parent writes the fragment, so
    workers never load pandas, which pyarrow imports on first use: 0.2 s of each worker's start)."""
    config, out_dir, shard = job
    cv2.setNumThreads(1)  # the parent decides parallelism
    out = Path(out_dir)
    start, cpu = time.perf_counter(), time.process_time()
    sampler = config.sampler()
    rows, evaluations, spent = [], 0, dict.fromkeys(STAGES, 0.0)
    last = time.perf_counter()

    def lap(stage: str) -> None:
        """Add the time since the last lap to a stage."""
        nonlocal last
        now = time.perf_counter()
        spent[stage] += now - last
        last = now

    frames = _frame_reader(config, shard)
    # Streamed to disk as it grows: a 1,000-sample full-size shard would be ~1 GB in memory.
    with config.writer(out).shard(shard) as tar:
        for index in config.shard_samples(shard):
            draw = sampler.draw(config.seed, index)
            evaluations += draw.evaluations
            bend = warp_columns(config.reference, sampler.reference_rect.crop, draw.calib, draw.rect.crop)
            lap("sample")
            raw_image = config.image_for(index)
            raw = _raw(raw_image, frames, config.channels)
            lap("decode")
            image = remap_image(raw, draw.rect, config.interp)
            lap("remap")
            data = encode_image(image, config.ext, config.encoder)
            lap("encode")
            row = _label_row(config, shard, index, raw_image, draw.is_reference, draw.rect, draw.appd_px, bend)
            tar.add_sample(row, config.ext, data)
            rows.append(row)
            lap("write")
    lap("write")
    if frames is not None:
        frames.close()
    stats = ShardStats(shard=shard, file=shard_name(shard), samples=len(rows), bytes=tar.size,
                       splits=dict(sorted(Counter(r["split"] for r in rows).items())),
                       references=sum(r["is_reference"] for r in rows), evaluations=evaluations,
                       stage_seconds=spent, seconds=time.perf_counter() - start,
                       cpu_seconds=time.process_time() - cpu)
    return stats, rows


def _frame_reader(config: BuildConfig, shard: int):
    """A recordings.FrameReader over the frames of a shard, or None for a build from image files."""
    if not config.from_recordings:
        return None
    from appdgen.sources.recordings import FrameReader

    return FrameReader([config.image_for(i).frame for i in config.shard_samples(shard)])


def _raw(image: RawImage, frames, channels: int) -> np.ndarray:
    """The raw image of a sample with `channels` (1 grey, 3 BGR): a frame from the shard's reader, else the file."""
    if image.frame is None:
        return _decoded(image.path, channels)
    try:
        return as_channels(frames.read(image.frame), channels)
    except AppdgenError as exc:
        raise RawImageError(str(exc)) from None


def _decoded(path: Path, channels: int = 3) -> np.ndarray:
    """A raw image, the last one a worker decoded kept for the next sample (consecutive samples share an image, and
    the next shard usually starts with the image the last one ended with); a file changed since is read anew."""
    try:
        stat = path.stat()
    except OSError:
        return read_raw(path, channels)  # names the file in its error
    return _decoded_version(path, stat.st_mtime_ns, stat.st_size, channels)


@functools.lru_cache(maxsize=1)
def _decoded_version(path: Path, mtime_ns: int, size: int, channels: int = 3) -> np.ndarray:
    """read_raw of one version of a file (the cache key)."""
    return read_raw(path, channels)


class RawImageError(AppdgenError):
    """A raw image that passed the checks before the build but does not decode in a worker."""


def read_raw(path: Path, channels: int = 3) -> np.ndarray:
    """A raw image for remapping (8-bit BGR, or grey for channels 1), refusing one cut short since the build began
    (it decodes grey)."""
    try:
        check_complete(path)
        return read_image(path, channels)
    except AppdgenError as exc:
        raise RawImageError(str(exc)) from None


def warp_columns(reference: Calibration, reference_crop: Crop, calib: Calibration, crop: Crop) -> dict[str, float]:
    """A sample's layout.BEND_COLUMNS: split_warp from the reference rectification (raw px, % of the raw diagonal,
    unitless scale); a reference sample exactly 0, 0, 0, 0, 1."""
    split = split_warp(reference, reference_crop, calib, crop)
    return bend_columns(split.bend_px, px_to_pct(split.bend_px, reference), split.shift_x_px, split.shift_y_px,
                        split.scale)


def _label_row(config: BuildConfig, shard: int, index: int, image: RawImage, is_reference: bool,
               rect: Rectification, distance_px: float, bend: dict[str, float]) -> dict:
    """One sample's label: perturbed Θ, K̂ of its crop, output size, APPD (px and % of the diagonal), its crop and
    its warp's split (`bend`, warp_columns)."""
    k = rect.new_camera_matrix
    return {
        "key": sample_key(index), "shard": shard_name(shard), "raw_path": image.name, "split": image.split,
        "camera": config.camera, "model": rect.calib.model, "sample_index": index, "is_reference": bool(is_reference),
        **rect.calib.params(),
        "new_fx": float(k[0, 0]), "new_fy": float(k[1, 1]), "new_cx": float(k[0, 2]), "new_cy": float(k[1, 2]),
        "width": config.size[0], "height": config.size[1],
        "appd_px": distance_px, "appd_pct": px_to_pct(distance_px, config.reference),
        **crop_columns(rect.crop.x0, rect.crop.y0, rect.crop.x1, rect.crop.y1), **bend,
        **(_frame_columns(image.frame) if image.frame is not None else {}),
    }


def _frame_columns(frame: Frame) -> dict:
    """A recording's frame as its labels.parquet source columns."""
    return source_columns(frame.source, frame.topic, frame.timestamp_ns, frame.number)


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


def _add_bend_columns(config: BuildConfig, writer: BuildWriter, done: list[int]) -> None:
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


def build(config: BuildConfig, out: Path, jobs: int = 1, backend: str = "loky", scheduler: str | None = None,
          resume: bool = False, overwrite: bool = False, progress: bool = True, command: list[str] | None = None,
          skipped: list[dict] | None = None) -> dict:
    """Run a build into `out` and return build.json's content (skipped: images left out, {"path", "problem"})."""
    start = time.perf_counter()
    check_parallel(jobs, backend)
    # Refuses bad --appd-max, --zero-fraction and --ranges, and an --appd-max the ranges cannot reach, here where
    # the build starts (a few dozen coarse APPD evaluations), before --out is touched, not in a worker; the sampler
    # is the one an in-process build (--jobs 1) goes on to use.
    config.sampler().check_reachable()
    config = prepare_out(out, config, resume, overwrite)
    writer = config.writer(out)
    todo = pending_shards(out, config)
    if resume:
        _add_bend_columns(config, writer, [k for k in range(config.shard_count) if k not in todo])
    bar = Progress(config.samples, enabled=progress,
                   done=config.samples - sum(len(config.shard_samples(k)) for k in todo))
    bar.advance(0, "resumed" if resume else "")
    made: dict[int, pa.Table] = {}  # this run's fragments, kept for the index (re-reading them cost ~3 ms each)
    try:
        for stats, rows in run_unordered(build_shard, [(config, str(out), k) for k in todo], jobs, backend, scheduler):
            made[stats.shard] = writer.shard_done(stats, rows)  # after the shard's tar: marks the shard done
            bar.advance(stats.samples, stats.file)
        return writer.finish(config.shard_count, made, lambda stats: _summary(
            config, stats, list(made), time.perf_counter() - start, command, skipped or []))
    except OSError as exc:
        raise AppdgenError(f"--out {out}: write failed ({exc.strerror or exc}); fix it and rerun with --resume") from None
    except UnreachableError as exc:
        raise AppdgenError(f"{exc}, then rebuild with --overwrite (--resume refuses other options)") from None
    except RawImageError as exc:
        raise AppdgenError(f"{exc} (finished shards are kept: replace the file and rerun with --resume, or leave it "
                           f"out and rebuild with --overwrite)") from None
    except AppdgenError as exc:
        raise AppdgenError(f"{exc} (finished shards are kept: fix this and rerun with --resume)") from None


def _summary(config: BuildConfig, shard_stats: list[ShardStats], built: list[int], seconds: float,
             command: list[str] | None, skipped: list[dict]) -> dict:
    """build.json: what was asked, what was written, how fast, with which libraries."""
    splits: Counter = Counter()
    for stats in shard_stats:
        splits.update(stats.splits)
    made = [s for s in shard_stats if s.shard in set(built)]
    drawn = sum(s.samples - s.references for s in shard_stats)
    return {
        **config.record(),
        "command": command or sys.argv,
        "counts": {"samples": config.samples, "shards": config.shard_count, "splits": dict(sorted(splits.items())),
                   "references": sum(s.references for s in shard_stats), "images": len(config.images),
                   "skipped_images": skipped},
        "shards": [s.listing() for s in shard_stats],
        "sampler": {"evaluations_per_sample": sum(s.evaluations for s in shard_stats) / max(drawn, 1),
                    "seconds_per_sample": sum(s.stage_seconds["sample"] for s in shard_stats) / max(drawn, 1)},
        "timings": {"wall_seconds": seconds, "shards_built": len(made), "shards_resumed": config.shard_count - len(made),
                    "samples_per_second": sum(s.samples for s in made) / seconds if seconds > 0 else None,
                    "mb_written": sum(s.bytes for s in made) / 1e6,
                    # Worker seconds per stage over this run's shards (all workers together).
                    "stage_seconds": {k: sum(s.stage_seconds[k] for s in made) for k in STAGES},
                    # … and their CPU seconds (below stage_seconds' sum where a worker waited: disk, a busy core).
                    "cpu_seconds": sum(s.cpu_seconds for s in made)},
        "libraries": _versions(config),
    }


def _versions(config: BuildConfig) -> dict:
    """Versions of Python and the libraries that shape the bytes (the PNG encoder's own package among them)."""
    import joblib
    import pyarrow
    import simplejpeg  # decodes JPEG inputs (sources/decode.py)

    encoder = get_encoder(config.encoder, config.channels)
    png = {encoder.library: encoder.version()} if config.image_format == "png" else {}
    return {"python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
            "pyarrow": pyarrow.__version__, "joblib": joblib.__version__, "simplejpeg": simplejpeg.__version__,
            **png}
