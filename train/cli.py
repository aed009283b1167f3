"""`python -m train fit|evaluate|predict|export`: the trainer's command line."""
from __future__ import annotations

import csv
import json
import sys
from dataclasses import asdict

import click

from appdgen.cli.base import recording_options, stack_options, start_plot
from appdgen.dataset.layout import TARGETS
from appdgen.detect import DEFAULT_THRESHOLD_PCT
from appdgen.errors import AppdgenError
from train.errors import TrainError
from train.nets import MODELS

DEVICE = click.option("--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "cuda"]))


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
def cli() -> None:
    """Train and use a CNN that predicts APPD (% of image diagonal) from appdgen's shards."""


def online_options(command):
    """fit's --online options: raw frames and a calibration, drawn and rendered as `appdgen build` would."""
    from appdgen.cli.base import CALIB_HELP, IMAGES_HELP, camera_option, sampling_options, size_option, split_by_option
    from train.online.options import RENDERS

    options = [
        click.option("--online", is_flag=True,
                     help="Train on fresh (frame, calibration) pairs drawn as it goes, from --calib and --images, "
                          "instead of --shards."),
        click.option("--calib", default=None, type=click.Path(dir_okay=False), help=CALIB_HELP),
        camera_option, click.option("--images", default=None, help=IMAGES_HELP), split_by_option, size_option,
        sampling_options,
        click.option("--render", default="auto", show_default=True, type=click.Choice(list(RENDERS)),
                     help="Where --online rectifies: cpu = loader workers with OpenCV, as build; device = the "
                          "training device (grid_sample; no lanczos4); auto = device on CUDA, else cpu."),
        recording_options,
        click.option("--val-shards", default=None,
                     help="--online: validate on this offline build (its val split, else its only split) instead "
                          "of fixed-seed pairs of held-out frames."),
    ]
    return stack_options(command, options)


def online_from(kw: dict) -> None:
    """Move the --online options out of fit's keywords into kw['online'] (an OnlineOptions, or None)."""
    from train.online.options import OnlineOptions

    names = [f for f in OnlineOptions.__dataclass_fields__]
    values = {n: kw.pop(n) for n in names}
    online = kw.pop("online")
    if not online:
        given = [n for n in ("calib", "images", "val_shards") if values[n] is not None]
        if given:
            raise TrainError(f"--{given[0].replace('_', '-')} needs --online")
        kw["online"] = None
        return
    missing = [n for n in ("calib", "images") if values[n] is None]
    if missing:
        raise TrainError(f"--online needs --{missing[0]}")
    kw["online"] = OnlineOptions(**values)


@cli.command()
@click.option("--shards", default=None, help="Folder written by `appdgen build` (its shards, label table and summary).")
@click.option("--run", "--run-dir", "run", required=True,
              help="Run folder: last.pt, best.pt, log.csv, config.json (--run-dir under torchrun, which claims --run).")
@click.option("--split", default="train", show_default=True,
              help="Split to train on (a build without it but with one split only: that one, e.g. 'all').")
@click.option("--val-split", default="auto", show_default=True,
              help="Validation split; 'auto' = 'val' if present else a raw-image holdout; 'holdout'; 'none'.")
@click.option("--val-fraction", default=0.1, show_default=True,
              help="Fraction of recordings (or raw images) held out, by hash of their name.")
@click.option("--val-by", default="recording", show_default=True, type=click.Choice(["recording", "image"]),
              help="Holdout unit: whole recordings (KITTI drive, else folder; a one-folder split falls back to "
                   "image) or single raw images.")
@click.option("--steps", type=click.IntRange(1), help="Total optimizer steps (counting resumed ones).")
@click.option("--epochs", type=click.FloatRange(0, min_open=True), help="Total passes over the training split.")
@click.option("--batch", default=32, show_default=True, type=click.IntRange(1), help="Images per step per rank.")
@click.option("--lr", default=1e-4, show_default=True, help="Adam learning rate.")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(0), help="DataLoader decode workers.")
@click.option("--ckpt-every", default=200, show_default=True, type=click.IntRange(1), help="Steps between checkpoints.")
@click.option("--val-every", type=click.IntRange(1), help="Steps between validations [default: --ckpt-every].")
@click.option("--val-max", default=1000, show_default=True, type=click.IntRange(1), help="Most validation images used.")
@click.option("--log-every", default=10, show_default=True, type=click.IntRange(1), help="Steps between log.csv rows.")
@click.option("--max-minutes", type=click.FloatRange(0, min_open=True),
              help="Stop early, validated and checkpointed, after this wall time (checked every --log-every steps).")
@click.option("--shuffle-buffer", default=1000, show_default=True, type=click.IntRange(1),
              help="Samples (encoded) mixed by the shuffle buffer of each loader worker.")
@click.option("--resume", is_flag=True,
              help="Continue from RUN/last.pt (starts fresh if there is none), the data from where it stopped.")
@click.option("--seed", default=0, show_default=True, help="Seed for weights and data order.")
@DEVICE
@click.option("--precision", default="auto", show_default=True, type=click.Choice(["auto", "fp32", "bf16"]),
              help="auto = bf16 autocast on CUDA and on CPUs with native bf16, else fp32.")
@click.option("--stats-samples", default=256, show_default=True, type=click.IntRange(1),
              help="Images used for the per-channel mean/std.")
@click.option("--normalize", default="channel", show_default=True, type=click.Choice(["channel", "pixel"]),
              help="Input normalisation: per-channel mean/std, or the released code's per-pixel mean image.")
@click.option("--target", default="appd", show_default=True, type=click.Choice(list(TARGETS)),
              help="What the network learns: appd = APPD (appd_pct, the paper's label); bend = its non-affine part "
                   "(bend_pct, what bends straight lines; from labels.parquet offline, from each draw online).")
@click.option("--model", default="paper", show_default=True, type=click.Choice(list(MODELS)),
              help="The model: the paper's CNN; patch (a stride-4 patchify stem: full-resolution detail at a "
                   "third of the paper CNN's cost at quarter size); plumbline (the classical floor: line "
                   "curvature and a ridge solved in closed form on --steps batches; no gradient steps). "
                   "`python -m studies.detector` compares them.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@online_options
def fit(**kw) -> None:
    """Train on one split of the shards (or --online on fresh pairs); prints a JSON summary."""
    from train.fit import fit as run_fit
    from train.options import FitOptions

    online_from(kw)
    summary = run_fit(FitOptions(**kw))
    if summary is not None:  # rank 0 only under torchrun
        click.echo(json.dumps(summary))


@cli.command()
@click.option("--ckpt", required=True, help="Checkpoint (.pt) written by fit.")
@click.option("--shards", default=None, help="Folder written by `appdgen build`.")
@click.option("--frames", default=None,
              help="Instead of --shards: raw frames the fit --online checkpoint has not seen (a folder, glob or "
                   "list, in file order), scored per frame and per sequence of --length frames under one "
                   "fixed-seed miscalibration of the fit's calibration and sampling.")
@click.option("--length", default=10, show_default=True, type=click.IntRange(1), help="--frames: frames a sequence.")
@click.option("--sequences", type=click.IntRange(1), help="--frames: most sequences [default: as the frames allow].")
@click.option("--draw-seed", type=int, help="--frames: seed of the sequences' miscalibrations [default: the "
                                            "detector comparison's, train.scoring.SEQUENCE_SEED].")
@click.option("--split", default="test", show_default=True)
@click.option("--json", "json_path", help="Also write the metrics to this JSON file.")
@click.option("--plot", "plot_path", help="Predicted-vs-true APPD plot (PNG; needs the 'plot' extra: matplotlib).")
@click.option("--threshold", default=DEFAULT_THRESHOLD_PCT, show_default=True,
              help="APPD % above which a camera needs recalibration (appdgen detect's).")
@click.option("--batch", default=64, show_default=True, type=click.IntRange(1))
@click.option("--workers", default=1, show_default=True, type=click.IntRange(0))
@DEVICE
@click.option("--precision", default="fp32", show_default=True, type=click.Choice(["auto", "fp32", "bf16"]))
def evaluate(ckpt: str, shards: str | None, frames: str | None, length: int, sequences: int | None,
             draw_seed: int | None, split: str, json_path: str | None, plot_path: str | None, threshold: float,
             batch: int, workers: int, device: str, precision: str) -> None:
    """MAE, RMSE, mean-predictor MAE, per-bin MAE and P/R/F1 of a checkpoint on one split (JSON); with --frames,
    on sequences of unseen raw frames, per frame and per sequence."""
    from train.evaluate import evaluate as run_eval
    from train.evaluate import evaluate_frames
    from train.scoring import summary_line

    if (shards is None) == (frames is None):
        raise TrainError("give --shards (a build and its --split) or --frames (raw frames of a fit --online run)")
    start_plot(plot_path)
    if frames is not None:
        if plot_path:
            raise TrainError("--plot needs --shards")
        result = evaluate_frames(ckpt, frames, length, sequences, draw_seed, json_path, threshold, batch, device,
                                 precision)
    else:
        result = run_eval(ckpt, shards, split, json_path, plot_path, threshold, batch, workers, device, precision)
    click.echo(json.dumps(result, indent=1))
    click.echo(f"evaluate: {summary_line(result)}", err=True)


@cli.command()
@click.argument("images", nargs=-1, required=True)
@click.option("--ckpt", required=True, help="Checkpoint (.pt) written by fit.")
@click.option("--calib", help="Calibration file: rectify raw images with it first (needs appdgen).")
@click.option("--camera", help="Camera id inside --calib, e.g. 02.")
@click.option("--max-fov", type=float, metavar="DEG",
              help="Crop bound for --calib [default: the training build's max_fov, recorded by fit; a different "
                   "value is refused, so this is for checkpoints that do not record one].")
@click.option("--threshold", default=DEFAULT_THRESHOLD_PCT, show_default=True,
              help="Recalibrate when the running median exceeds this APPD %.")
@click.option("--window", default=9, show_default=True, type=click.IntRange(1), help="Running-median length (images).")
@click.option("--batch", default=32, show_default=True, type=click.IntRange(1))
@click.option("--resize", is_flag=True, help="Rescale rectified images of another size to the network's.")
@click.option("--csv", "as_csv", is_flag=True, help="CSV output.")
@click.option("--json", "as_json", is_flag=True, help="JSON output (printed at the end; text and CSV stream).")
@recording_options
@click.option("--skip-bad", is_flag=True,
              help="Skip undecodable images or frames of a recording, e.g. a corrupt JPEG body (counted at the end).")
@DEVICE
def predict(images: tuple[str, ...], ckpt: str, calib: str | None, camera: str | None, max_fov: float | None,
            threshold: float, window: int, batch: int, resize: bool, as_csv: bool, as_json: bool, topic: str | None,
            every: int, min_interval: float, start: float | None, end: float | None, skip_bad: bool,
            device: str) -> None:
    """Predicted APPD per image of a sequence (IMAGES… or a folder, or one ROS bag or video: its frames with their
    timestamps), running median and verdict."""
    from train.predict import PredictFrames, predict_stream, trained_target

    if as_csv and as_json:
        raise click.UsageError("--csv and --json are exclusive")
    frames = PredictFrames(topic, every, min_interval, start, end, skip_bad)
    preds = predict_stream(ckpt, list(images), calib, camera, threshold, window, batch, resize, device, max_fov,
                           frames)
    rows, writer, count, last = [], None, 0, None
    for last in preds:
        count += 1
        row = asdict(last)
        if row["timestamp_ns"] is None:  # image files: the columns as before
            del row["timestamp_ns"]
        if as_json:
            rows.append(row)
        elif as_csv:
            writer = writer or csv.DictWriter(sys.stdout, fieldnames=list(row))
            if count == 1:
                writer.writeheader()
            writer.writerow(row)
        else:
            stamp = "" if last.timestamp_ns is None else f"{last.timestamp_ns}\t"
            click.echo(f"{stamp}{last.path}\t{last.appd_pct:7.3f}\t{last.running_median:7.3f}\t"
                       f"{'recalibrate' if last.recalibrate else 'ok'}")
    target = trained_target(ckpt)
    summary = {"images": count, "running_median": last.running_median, "threshold": threshold,
               "verdict": "recalibrate" if last.recalibrate else "ok", "skipped_frames": len(frames.skipped),
               "target": target}
    if as_json:
        click.echo(json.dumps({"predictions": rows, "summary": summary}, indent=1))
    elif not as_csv:
        skipped = f", {len(frames.skipped)} undecodable frames skipped" if frames.skipped else ""
        trained = "" if target == "appd" else f" of {TARGETS[target]}"
        click.echo(f"# {count} images{skipped}, running median{trained} {last.running_median:.3f}% "
                   f"(window {window}) vs threshold {threshold:g}%: {summary['verdict']}")


@cli.command()
@click.option("--ckpt", required=True, help="Checkpoint (.pt) written by fit.")
@click.option("--onnx", "onnx_path", help="ONNX file to write (needs onnx + onnxscript).")
@click.option("--pt2", "pt2_path", help="torch.export program to write (.pt2; load with torch.export.load). "
                                        "TorchScript is not offered: torch 2.13 deprecates torch.jit.")
@click.option("--json", "json_path", help="--model plumbline: the floor's JSON, which train.plumbline reads "
                                          "without torch.")
def export(ckpt: str, onnx_path: str | None, pt2_path: str | None, json_path: str | None) -> None:
    """Export to ONNX and/or a torch.export .pt2 (the plumb-line floor: --json) and print the parity vs eager
    (max |diff| ≤ 1e-4)."""
    from train.export import export as run_export

    run_export(ckpt, onnx_path, pt2_path, json_path)


def user_errors() -> tuple[type[Exception], ...]:
    """Exception types shown as one line: ours, and appdgen's (calibrations, frames, builds, the floor)."""
    return (TrainError, AppdgenError)


def main(argv: list[str] | None = None, command: click.Command | None = None, prog_name: str = "python -m train"
         ) -> None:
    """Entry point of the trainer's CLI (or of `command`, e.g. a study's): one-line errors with exit status 2, and a
    clear message when torch is missing."""
    try:
        import torch  # noqa: F401 - only to give a clear message
    except ImportError:
        click.echo("error: the trainer needs PyTorch: pip install torch==2.13.0 (CPU) && pip install -e '.[train]'",
                   err=True)
        sys.exit(2)
    try:
        (command or cli).main(args=argv, prog_name=prog_name, standalone_mode=False)
    except click.exceptions.Abort:
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except user_errors() as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2)
