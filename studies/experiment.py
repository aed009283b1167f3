"""The paper-scale experiment in one call: synthesize frames, build samples, fit the paper's CNN, evaluate.

Train, validation and test frames come from three seeds (three recordings: no scene is shared), all rendered by
the bundled KITTI camera 02 mounted as on a car. Online (the default): fit trains on fresh pairs of the `train`
frames drawn as it goes (`fit --online`, rendered on the device on CUDA, bicubic), validating on fixed-seed pairs
of the `val` frames, and only the `test` frames are built, for evaluate. Offline (--offline): one build labels
every split (split = folder) and fit trains on its `train` shards. Either way fit runs for a wall-clock budget,
keeping the checkpoint best on `val`, and evaluate scores it on `test`. Every stage is the library call behind
the matching command (appdgen synth, appdgen build, python -m train fit / evaluate).

    python -m studies.experiment [--tiny] [--offline] [--detector] [--out runs/paper-scale] [--minutes 6] ...
"""
from __future__ import annotations

import math
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import click

from appdgen.synth import scale_calibration
from train.cli import main as train_main
from train.errors import TrainError
from train.model import min_side
from train.nets import MODELS
from train.scoring import summary_line as evaluation_line

#: Splits = folders under OUT/raw, each from its own seed offset.
SPLIT_SEEDS = {"train": 0, "val": 1, "test": 2}


@dataclass(frozen=True)
class ExperimentOptions:
    """Sizes of every stage; the defaults are the accelerator run sized in docs/studies/accelerator-experiment.md."""

    out: str = "runs/paper-scale"
    frames: int = 2000  # train frames (full-size KITTI 02 scenes)
    val_frames: int = 50
    test_frames: int = 100
    samples: int = 20000  # train samples; val and test frames get as many per frame
    scale: float = 1.0  # 1.0 = 1392x512, 0.25 = 348x128
    image_format: str = "png"
    #: fit's wall-clock budget (online: no train build, so ~2 of the 9 minutes more than offline's 4)
    minutes: float = 6.0
    steps: int | None = None  # a step budget instead (tests)
    batch: int = 32
    lr: float = 1e-4
    normalize: str = "channel"
    jobs: int | None = None  # synth and build processes [default: all cores]
    workers: int | None = None  # DataLoader workers [default: all cores on CUDA, 1 on CPU]
    device: str = "auto"
    seed: int = 0
    mount: str = "car"
    online: bool = True  # fit on fresh pairs (fit --online); False: build every split and fit on the shards
    model: str = "paper"  # fit --model
    overwrite: bool = False
    quiet: bool = False


#: Small enough for 2 CPU cores in under 3 minutes: proves the chain, not the quality.
TINY = dict(out="runs/paper-scale-tiny", frames=48, val_frames=8, test_frames=16, samples=960, scale=0.25,
            minutes=1.0)


def with_tiny_sizes(opts: ExperimentOptions) -> ExperimentOptions:
    """opts with TINY's sizes wherever they are still the full run's defaults."""
    full = ExperimentOptions()
    return replace(opts, **{k: v for k, v in TINY.items() if getattr(opts, k) == getattr(full, k)})


def per_frame(opts: ExperimentOptions) -> int:
    """Samples drawn per frame so that the train split holds at least opts.samples."""
    return max(1, math.ceil(opts.samples / opts.frames))


def check(opts: ExperimentOptions) -> None:
    """Refuse impossible sizes before anything is written."""
    for name in ("frames", "val_frames", "test_frames", "samples", "batch"):
        if getattr(opts, name) < 1:
            raise TrainError(f"--{name.replace('_', '-')} {getattr(opts, name)}: must be at least 1")
    if not 0 < opts.scale <= 1:
        raise TrainError(f"--scale {opts.scale}: must be in (0, 1]")
    w, h = scale_calibration(bundled_camera(), opts.scale).size
    if min(w, h) < min_side():  # refused now, not after minutes of synth and build
        raise TrainError(f"--scale {opts.scale}: {w}x{h} images are too small for the network ({min_side()} px)")
    if (opts.steps is None) == (opts.minutes is None):
        raise TrainError("give exactly one of --minutes or --steps")
    out = Path(opts.out)
    if out.exists() and any(out.iterdir()) and not opts.overwrite:
        raise TrainError(f"--out {out}: not empty; pass --overwrite to replace it")


def bundled_camera():
    """KITTI 2011_09_26 camera 02, the calibration shipped with appdgen (1392x512)."""
    from appdgen.calib.defaults import DEFAULT_CALIB_PATH
    from appdgen.calib.formats import load

    return load(DEFAULT_CALIB_PATH, "02")


def synthesize_frames(opts: ExperimentOptions, raw: Path, jobs: int) -> Path:
    """raw/{train,val,test}/frame_*.png and raw/calibration.yaml; returns the calibration's path."""
    from appdgen.calib.formats import save
    from appdgen.synth import MOUNTS, calibration_name, synthesize

    calib = bundled_camera()
    counts = {"train": opts.frames, "val": opts.val_frames, "test": opts.test_frames}
    for split, offset in SPLIT_SEEDS.items():
        seed = 3 * opts.seed + offset + 1  # distinct for every (seed, split): no frame is in two splits
        synthesize(calib, counts[split], raw / split, seed, opts.scale, jobs=jobs, mount=MOUNTS[opts.mount])
    scaled = scale_calibration(calib, opts.scale)
    path = raw / calibration_name(scaled)
    save(scaled, path)
    return path


#: The online run's interpolation (fit and test build alike): grid_sample's bicubic, which the device renders.
ONLINE_INTERP = "cubic"


def build_samples(opts: ExperimentOptions, raw: Path, calib_path: Path, shards: Path, jobs: int) -> dict:
    """One build over raw/ (split = folder; online: the test frames only), per_frame(opts) samples per frame;
    returns build.json."""
    from appdgen.calib.formats import load
    from appdgen.dataset.build import BuildConfig, build
    from appdgen.sources.files import list_images

    images = [i for i in list_images(str(raw), "parent") if not opts.online or i.split == "test"]
    total = per_frame(opts) * len(images)
    # Enough shards that every process has two: shards are the build's unit of parallel work.
    shard_size = max(1, min(1000, math.ceil(total / (2 * jobs))))
    reference = load(calib_path)
    config = BuildConfig(reference=reference, camera="02", calib_path=str(calib_path), images=tuple(images),
                         samples=total, size=reference.size, image_format=opts.image_format, shard_size=shard_size,
                         seed=opts.seed, **({"interp": ONLINE_INTERP} if opts.online else {}))
    return build(config, shards, jobs, progress=not opts.quiet, overwrite=True)


def run(opts: ExperimentOptions) -> dict:
    """All stages; returns the test metrics, the fit summary and each stage's seconds."""
    from appdgen.util.distribute import default_jobs
    from train import runtime
    from train.evaluate import evaluate
    from train.fit import FitOptions, fit
    from train.online.options import OnlineOptions

    check(opts)
    out = Path(opts.out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    device = runtime.pick_device(opts.device)
    cores = default_jobs()
    jobs = opts.jobs or cores
    workers = opts.workers if opts.workers is not None else (cores if device.type == "cuda" else 1)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[stage] = now - clock
        clock = now

    calib_path = synthesize_frames(opts, out / "raw", jobs)
    lap("synth")
    built = build_samples(opts, out / "raw", calib_path, out / "shards", jobs)
    lap("build")
    online = OnlineOptions(calib=str(calib_path), images=str(out / "raw"), split_by="parent",
                           interp=ONLINE_INTERP) if opts.online else None
    fitted = fit(FitOptions(
        shards=None if online else str(out / "shards"), run=str(out / "run"), split="train", val_split="val",
        online=online,
        steps=opts.steps or 10**9, max_minutes=None if opts.steps else opts.minutes, batch=opts.batch, lr=opts.lr,
        workers=workers, ckpt_every=500, val_max=min(500, opts.val_frames * per_frame(opts)),  # offline's val count
        log_every=10, seed=opts.seed, device=opts.device,
        normalize=opts.normalize, model=opts.model, quiet=opts.quiet,
    ))
    lap("fit")
    best = Path(fitted["best"] or fitted["last"])
    result = evaluate(str(best), str(out / "shards"), "test", json_path=str(out / "eval.json"), workers=workers,
                      device=opts.device)
    lap("evaluate")
    splits = {"train": None if opts.online else built["counts"]["splits"].get("train", 0),
              **{k: v for k, v in built["counts"]["splits"].items() if k != "train"}}
    return {"test": result, "fit": fitted, "seconds": seconds, "splits": splits, "frames": opts.frames,
            "size": built["size"], "device": str(device), "workers": workers, "jobs": jobs}


def summary_line(r: dict) -> str:
    """The experiment's one printed line: test MAE vs the mean predictor, training speed, each stage's time."""
    s = r["seconds"]
    train = r["splits"].get("train")
    seen = f"fresh pairs of {r['frames']} frames, {r['fit'].get('render')} render" if train is None else \
        f"{train} samples"
    stages = ", ".join(f"{name} {sec:.0f} s" for name, sec in s.items())
    w, h = r["size"]
    return (f"paper-scale: {evaluation_line(r['test'])}; train {r['fit']['images_per_s'] or 0:.0f} images/s, "
            f"{r['fit']['images']} images ({seen}) at {w}x{h} on {r['device']}; {stages}; total "
            f"{sum(s.values()):.0f} s")


def detector_options(opts: ExperimentOptions, tiny_sizes: bool = False):
    """The detector comparison (studies.detector) at this experiment's sizes: --frames training streets, --samples
    images per arm, --test-frames split into sequences of 10; TINY's sizes with `tiny_sizes`."""
    from studies.detector import TINY as DETECTOR_TINY
    from studies.detector import DetectorOptions

    o = DetectorOptions(out=opts.out, frames=opts.frames, sequences=max(1, opts.test_frames // 10),
                        images=opts.samples, batch=opts.batch, seed=opts.seed, device=opts.device,
                        jobs=opts.jobs or 1)
    return replace(o, **DETECTOR_TINY) if tiny_sizes else o


def run_detector(o) -> dict:
    """Every arm of the detector comparison (in-process, one stream after the other); returns its summary."""
    from studies.detector import run as run_arms
    from train import runtime

    device = runtime.pick_device(o.device)
    return run_arms(replace(o, device=device.type), parallel=device.type == "cpu")


def _sized(name: str, help_text: str, **kw):
    """An option whose default lives in ExperimentOptions (shown in the help, applied there)."""
    attr = name.lstrip("-").replace("-", "_")
    default = getattr(ExperimentOptions(), "image_format" if attr == "format" else attr, None)
    shown = f" [default: {default}]" if default is not None else ""
    return click.option(name, attr, default=None, help=help_text + shown, **kw)


@click.command(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@_sized("--out", "Run folder (runs/paper-scale-tiny with --tiny).")
@click.option("--tiny", is_flag=True, help="Small sizes for 2 CPU cores (< 3 min): proves the chain, not the quality.")
@_sized("--frames", "Train frames.", type=click.IntRange(1))
@_sized("--val-frames", "Validation frames (a third seed).", type=click.IntRange(1))
@_sized("--test-frames", "Test frames (a second seed).", type=click.IntRange(1))
@_sized("--samples", "Train samples; val and test frames get as many per frame.", type=click.IntRange(1))
@_sized("--scale", "Camera scale: 1 = 1392x512, 0.25 = 348x128.", type=float)
@_sized("--format", "Shard image encoding.", type=click.Choice(["png", "npy"]))
@_sized("--minutes", "Fit's wall-clock budget.", type=click.FloatRange(0, min_open=True))
@_sized("--steps", "A step budget instead of --minutes.", type=click.IntRange(1))
@_sized("--batch", "Images per step.", type=click.IntRange(1))
@_sized("--lr", "Adam learning rate.", type=float)
@_sized("--normalize", "Input normalisation.", type=click.Choice(["channel", "pixel"]))
@_sized("--jobs", "Synth and build processes [default: all cores].", type=click.IntRange(1))
@_sized("--workers", "DataLoader workers [default: all cores on CUDA, 1 on CPU].", type=click.IntRange(0))
@_sized("--device", "auto, cpu or cuda.", type=click.Choice(["auto", "cpu", "cuda"]))
@_sized("--seed", "Seed of frames, samples, weights and data order.", type=int)
@_sized("--mount", "Synthetic camera pose spread (appdgen synth --mount).", type=click.Choice(["car", "loose"]))
@click.option("--offline", is_flag=True,
              help="Build every split and fit on the shards, instead of fit --online on fresh pairs of the frames.")
@_sized("--model", "fit --model.", type=click.Choice(list(MODELS)))
@click.option("--detector", is_flag=True,
              help="Run the detector comparison instead (studies.detector: every arm × target on --samples fresh "
                   "pairs each, tested on the training views, a new viewpoint and unseen streets); prints its table.")
@click.option("--overwrite", is_flag=True, help="Replace a previous run in --out.")
@click.option("--quiet", is_flag=True, help="No progress lines.")
def experiment(tiny: bool, offline: bool, detector: bool, **kw) -> None:
    """Synthesize full-size KITTI 02 frames, fit the paper's CNN on fresh pairs of them (or --offline on a build),
    evaluate on built test frames; prints one line."""
    given = {k: v for k, v in kw.items() if v is not None}
    if "steps" in given:
        given["minutes"] = None
    opts = ExperimentOptions(online=not offline,
                             **{"image_format" if k == "format" else k: v for k, v in given.items()})
    if detector:
        from studies.detector import table

        o = detector_options(opts, tiny)
        # explicit sizes win over --tiny's
        o = replace(o, **{k: v for k, v in {"frames": given.get("frames"), "images": given.get("samples")}.items()
                          if v is not None})
        click.echo(table(run_detector(o)["rows"]))
        return
    click.echo(summary_line(run(with_tiny_sizes(opts) if tiny else opts)))


def main(argv: list[str] | None = None) -> None:
    """`python -m studies.experiment`: the trainer's one-line errors (exit 2) and torch check."""
    train_main(argv, experiment, "python -m studies.experiment")


if __name__ == "__main__":
    main()
