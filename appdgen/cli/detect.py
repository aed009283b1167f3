"""`appdgen detect`: how far a believed calibration is from the camera that took the frames, per frame and per
sequence, read from straight edges (a thin layer over appdgen.detect)."""
from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click

from appdgen.cli.base import (
    calib_option,
    camera_option,
    describe_source,
    fail_cleanly,
    format_table,
    images_option,
    main,
    max_fov_option,
    modified,
    perturb_option,
    plot_option,
    recording_options,
    set_option,
    start_plot,
)
from appdgen.detect import DEFAULT_SEQUENCE, DEFAULT_THRESHOLD_PCT
from appdgen.detect.simulate import SIMULATED
from appdgen.errors import AppdgenError

#: A reading's fields in a frame's JSON object (after `image`); a sequence's add `offsets`.
FRAME_FIELDS = ("appd_pct", "appd_sd_pct", "bend_pct", "bend_sd_pct", "p_above", "verdict", "segments", "reason",
                "raw_appd_pct", "raw_appd_sd_pct")
SEQUENCE_FIELDS = (*FRAME_FIELDS, "offsets")
MISCALIBRATED = "miscalibrated"  # the verdict counted as a flag
SENSITIVITY_WIDTH = 348  # px: output width of the per-parameter APPD rates (KITTI at quarter size)
STEP_ZERO = 1e-4  # the step of a parameter whose believed value is zero (a lens coefficient)


@dataclass
class Report:
    """What the command found: one JSON object per frame and per sequence, and the counts for the summary."""

    frames: list[dict] = field(default_factory=list)
    sequences: list[dict] = field(default_factory=list)
    seconds: float = 0.0  # the frame loop's wall time: decoding, evidence and solves

    @property
    def abstained(self) -> int:
        """Frames without a reading."""
        return sum(f["appd_pct"] is None for f in self.frames)

    @property
    def flagged(self) -> int:
        """Sequences whose verdict is miscalibrated."""
        return sum(s["verdict"] == MISCALIBRATED for s in self.sequences)


def writable_target(option: str, path: str) -> Path:
    """An output file's path, refused before any work when it cannot be written (a folder, or under no writable
    folder)."""
    target = Path(path)
    if target.is_dir():
        raise AppdgenError(f"{option} {path}: is a folder")
    folder = target.absolute().parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise AppdgenError(f"{option} {path}: cannot write there ({folder} is not a writable folder)")
    return target


def output_targets(json_path: str | None, save_path: str | None, baseline_path: str | None,
                   changed: bool, plot_path: str | None = None) -> dict[str, Path]:
    """The output files by option, refused before any work when the options contradict or a file is unwritable."""
    if save_path and baseline_path:
        raise AppdgenError("give --baseline or --save-baseline, not both")
    if save_path and changed:
        raise AppdgenError("--save-baseline records the calibration the camera was calibrated with: no --set/--perturb")
    return {option: writable_target(option, path) for option, path in
            (("--json", json_path), ("--save-baseline", save_path), ("--plot", plot_path)) if path}


def load_baseline(path: str | None) -> Any:
    """The --baseline file's Baseline (one-line error naming a bad or foreign file), or None."""
    from appdgen.detect import Baseline

    return Baseline.from_json(Path(path)) if path else None


def write_json(target: Path, document: dict) -> None:
    """The --json document, written atomically."""
    from appdgen.util.atomic import write_file

    write_file(target, (json.dumps(document, indent=1) + "\n").encode("utf-8"))


def fields_of(reading: Any, names: Sequence[str]) -> dict:
    """The named fields of a Reading's JSON form, in that order."""
    data = reading.to_dict()
    return {name: data.get(name) for name in names}


def groups(items: Iterator, size: int) -> Iterator[list]:
    """Consecutive groups of `size` items (the last may be shorter), holding one group at a time."""
    group: list = []
    for item in items:
        group.append(item)
        if len(group) == size:
            yield group
            group = []
    if group:
        yield group


def read_frames(detector: Any, images: Sequence, sequence: int, baseline: Any, threshold: float, bar: Any,
                kept: list | None = None) -> Report:
    """Read every frame alone and every `sequence` consecutive frames pooled in one solve, decoding one frame at a
    time; `kept` collects every frame's evidence (for a baseline)."""
    from appdgen.sources.inputs import iter_images

    report = Report()
    start = time.perf_counter()
    evidence = (detector.evidence(raw, image.name) for raw, image in zip(iter_images(images, channels=1), images,
                                                                             strict=False))
    first = 0
    for group in groups(evidence, sequence):
        for one in group:
            reading = detector.read([one], baseline, threshold)
            report.frames.append({"image": one.name, **fields_of(reading, FRAME_FIELDS)})
            bar.advance(1)
        pooled = detector.read(group, baseline, threshold)
        report.sequences.append({"first": first, "first_image": group[0].name, "count": len(group),
                                 **fields_of(pooled, SEQUENCE_FIELDS)})
        first += len(group)
        if kept is not None:
            kept.extend(group)
    report.seconds = time.perf_counter() - start
    return report


def plus_minus(mean: float | None, sd: float | None) -> str:
    """'0.31±0.12', or '—' without a value."""
    return "—" if mean is None else f"{mean:.2f}±{sd:.2f}"


def appd_per_unit(belief: Any, max_fov: float | None) -> dict[str, float]:
    """APPD (% of the raw diagonal) per unit change of each of the belief's parameters: a step of 1 % of its value
    (STEP_ZERO when zero), on an output about SENSITIVITY_WIDTH px wide (APPD in % barely depends on the size)."""
    from appdgen.geometry.appd import appd

    scale = max(1.0, belief.width / SENSITIVITY_WIDTH)
    size = (round(belief.width / scale), round(belief.height / scale))
    rates = {}
    for name, value in belief.params().items():
        step = 0.01 * abs(value) or STEP_ZERO
        rates[name] = appd(belief, belief.replace(**{name: value + step}), size, max_fov)[1] / step
    return rates


def most_moved(offsets: dict[str, dict], rates: dict[str, float]) -> str:
    """The parameter whose offset alone moves the rectified pixels most (to first order): 'cx -16.9±0.5 (≈1.07 %
    alone)'; '' without offsets."""
    if not offsets:
        return ""
    name, value = max(offsets.items(), key=lambda item: abs(item[1]["mean"]) * rates.get(item[0], 0.0))
    return f"{name} {value['mean']:+.3g}±{value['sd']:.2g} (≈{abs(value['mean']) * rates.get(name, 0.0):.2f} % alone)"


def row(label: str, entry: dict) -> list[str]:
    """A table row: label, APPD, bend, probability above the threshold, segments and verdict (or why abstained)."""
    p_above = "—" if entry["p_above"] is None else f"{entry['p_above']:.2f}"
    verdict = entry["verdict"] if entry["reason"] is None else f"{entry['verdict']}: {entry['reason']}"
    return [label, plus_minus(entry["appd_pct"], entry["appd_sd_pct"]),
            plus_minus(entry["bend_pct"], entry["bend_sd_pct"]), p_above, str(entry["segments"]), verdict]


def frame_span(first: int, count: int) -> str:
    """'0-9' for frames 0 to 9 (counted from 0 in input order), '7' for frame 7 alone."""
    return f"{first}-{first + count - 1}" if count > 1 else str(first)


def text_report(report: Report, threshold: float, quiet: bool, rates: dict[str, float]) -> str:
    """The readable tables: every frame (unless quiet), then every sequence with the parameter that moved most."""
    header = ["APPD %", "bend %", f"P(>{threshold:g}%)", "segments", "verdict"]
    parts = []
    if not quiet:
        parts.append(format_table(["frame", *header], [row(f["image"], f) for f in report.frames]))
    sequences = [[*row(frame_span(s["first"], s["count"]), s), most_moved(s["offsets"], rates)]
                 for s in report.sequences]
    parts.append(format_table(["frames", *header, "moved most (true - belief)"], sequences))
    return "\n\n".join(parts)


def summary(report: Report, inputs: Any, calib_path: str, options: dict, model_seconds: float) -> dict:
    """The JSON summary: what was read with which belief, what was found, and how fast."""
    belief = inputs.reference
    return {"calibration": calib_path, "camera": inputs.camera, "model": belief.model, "size": list(belief.size),
            **options, "frames": len(report.frames), "abstained": report.abstained, "skipped": inputs.skipped,
            "sequences": len(report.sequences), "sequences_flagged": report.flagged,
            "model_seconds": round(model_seconds, 3),
            "frames_per_second": round(len(report.frames) / report.seconds, 3) if report.seconds > 0 else None}


def title(info: dict) -> str:
    """What was read against what: 'belief folder/calibration.yaml camera 0 (radtan 348x128), against a baseline …'."""
    against = f"against the baseline {info['baseline']}" if info["baseline"] else "against straight lines"
    changes = "".join(f" --{option} {item}" for option in ("set", "perturb") for item in info[option])
    width, height = info["size"]
    return (f"belief {describe_source(info['calibration'], info['camera'])}{changes} ({info['model']} "
            f"{width}x{height}), {against}")


def closing_line(info: dict, json_path: str | None) -> str:
    """One line: frames, abstentions, sequences flagged above the threshold, speed, and where the JSON went."""
    where = f" -> {json_path}" if json_path else ""
    rate = f", {info['frames_per_second']:.1f} frames/s" if info["frames_per_second"] else ""
    return (f"{info['frames']} frames ({info['abstained']} abstained), {info['sequences']} sequences of "
            f"{info['sequence']}: {info['sequences_flagged']} flagged above {info['threshold_pct']:g} % APPD "
            f"(model {info['model_seconds']:.1f} s{rate}){where}")


def draw_plot(target: Path, detector: Any, images: Sequence, report: Report, baseline: Any, threshold: float,
              heading: str) -> None:
    """The --plot figure: the windows' readings, and the first frame's edge points by weight with the solved field."""
    from appdgen.analysis.plots import plot_detect
    from appdgen.sources.inputs import iter_images

    raw = next(iter(iter_images(images[:1], channels=1)))
    evidence = detector.evidence(raw)
    points = evidence.points
    estimate = detector.estimate([evidence], baseline)
    weight = estimate.seg_weight[points.seg] if estimate.seg_weight is not None else points.u * 0
    model = detector.model
    plot_detect(target, report.sequences, threshold, detector.rectify(raw), (points.u, points.v, weight),
                (model.grid_u, model.grid_v, model.field_of(estimate.c)), heading)


@main.command()
@calib_option
@camera_option
@images_option
@click.option("--sequence", default=DEFAULT_SEQUENCE, show_default=True, type=click.IntRange(min=1), metavar="N",
              help="Frames pooled per sequence: consecutive groups of N (the last holds what is left).")
@click.option("--threshold", "threshold_pct", default=DEFAULT_THRESHOLD_PCT, show_default=True, metavar="PCT",
              type=click.FloatRange(min=0.0, min_open=True),
              help="APPD (% of the raw diagonal) above which the belief counts as miscalibrated.")
@click.option("--baseline", "baseline_path", default=None, type=click.Path(dir_okay=False),
              help="Read against this camera's baseline (--save-baseline) instead of against straight lines.")
@click.option("--save-baseline", "save_path", default=None, type=click.Path(dir_okay=False),
              help="Record how these frames read under --calib (the calibration the camera was calibrated with) "
                   "as the camera's baseline, to this JSON file, with the camera's map from readings to APPD "
                   f"(learnt from {SIMULATED} simulated beliefs around --calib; about a minute more on one core).")
@click.option("--json", "json_path", default=None, type=click.Path(dir_okay=False),
              help="Also write every frame's and sequence's reading and a summary to this JSON file.")
@set_option
@perturb_option
@max_fov_option
@recording_options
@click.option("--skip-bad", is_flag=True,
              help="Skip frames of the wrong size, truncated or unreadable (listed in the JSON summary); else the "
                   "first is an error.")
@click.option("--quiet", is_flag=True, help="No progress line and no per-frame lines: only the sequences.")
@plot_option
@fail_cleanly
def detect(calib_path, camera, images_spec, sequence, threshold_pct, baseline_path, save_path, json_path, sets,
           perturbs, max_fov, topic, every, min_interval, start, end, skip_bad, quiet, plot_path):
    """Say how far the believed calibration (--calib) is from the camera that took the frames, from straight edges:
    APPD and its non-affine part (bend) per frame and per sequence, with their uncertainty and a verdict."""
    from appdgen.detect import Detector
    from appdgen.sources.inputs import resolve_inputs
    from appdgen.sources.recordings import FrameChoice
    from appdgen.util.progress import Progress

    start_plot(plot_path)
    targets = output_targets(json_path, save_path, baseline_path, sets or perturbs, plot_path)
    baseline = load_baseline(baseline_path)
    inputs = resolve_inputs(images_spec, calib_path, camera, "none", topic,
                            FrameChoice(every, min_interval, start, end), skip_bad, check_grey=False)
    belief = modified(inputs.reference, sets, perturbs)
    if baseline is not None:
        baseline.check(belief)  # a foreign baseline is refused before the model is built
    detector = Detector(belief, max_fov, progress=None if quiet else lambda text: click.echo(text, err=True))
    kept: list | None = [] if save_path else None
    bar = Progress(len(inputs.images), unit="frames", enabled=not quiet)
    try:
        report = read_frames(detector, inputs.images, sequence, baseline, threshold_pct, bar, kept)
    finally:
        bar.close()
    if save_path:
        sim_bar = Progress(SIMULATED, unit="simulated beliefs (the camera's map)", enabled=not quiet)
        try:
            saved = detector.save_baseline(kept, source=images_spec, progress=lambda done, _: sim_bar.update(done))
        finally:
            sim_bar.close()
        saved.to_json(targets["--save-baseline"])
    options = {"images": images_spec, "set": list(sets), "perturb": list(perturbs), "max_fov": max_fov,
               "sequence": sequence, "threshold_pct": threshold_pct, "baseline": baseline_path,
               "saved_baseline": save_path}
    info = summary(report, inputs, calib_path, options, detector.seconds_to_model)
    if json_path:
        write_json(targets["--json"], {"frames": report.frames, "sequences": report.sequences, "summary": info})
    click.echo(title(info))
    click.echo(text_report(report, threshold_pct, quiet, appd_per_unit(belief, max_fov)))
    click.echo(closing_line(info, json_path))
    if plot_path:
        draw_plot(targets["--plot"], detector, inputs.images, report, baseline, threshold_pct, title(info))
    if save_path:
        click.echo(f"baseline of {len(kept)} frames under {calib_path} -> {save_path}")
