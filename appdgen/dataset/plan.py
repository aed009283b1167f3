"""A build's plan: everything that decides its bytes (BuildConfig: inputs, options, seed), described by content
(hashes of the calibration file and of the images' resolved paths) for plan.json, and a resume checked against it."""
from __future__ import annotations

import dataclasses
import functools
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

from appdgen.calib.calibration import Calibration
from appdgen.dataset.encoders import DEFAULT_ENCODER, LEGACY_ENCODER, get_encoder
from appdgen.dataset.layout import FORMATS
from appdgen.dataset.shards import BuildWriter
from appdgen.errors import AppdgenError
from appdgen.geometry.crop import check_max_fov, check_output_size, valid_region
from appdgen.geometry.remap import DEFAULT_INTERP
from appdgen.sampling.options import DEFAULT_ZERO_FRACTION, SamplingOptions
from appdgen.sampling.ranges import Range, default_ranges
from appdgen.sampling.sampler import DEFAULT_APPD_MAX, Sampler
from appdgen.sources.frames import RawImage
from appdgen.version import __version__

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
        sources = dict(zip((s for s, _ in self.recordings), record.get("recordings", ()), strict=False))
        images = tuple(dataclasses.replace(i, name=name, split=split, frame=i.frame and dataclasses.replace(
                           i.frame, source=sources.get(i.frame.source, i.frame.source)))
                       for i, (name, split) in zip(self.images, record["images"], strict=False))
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
