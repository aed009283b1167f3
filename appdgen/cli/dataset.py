"""CLI commands for datasets: synthesize raw frames, build shards, inspect and verify them, write image lists."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import click

from appdgen.cli.base import (
    calib_option,
    camera_option,
    fail_cleanly,
    images_option,
    load_calibration,
    main,
    recording_options,
    sampling_options,
    size_option,
    split_by_option,
)
from appdgen.dataset.encoders import DEFAULT_ENCODER, ENCODERS
from appdgen.dataset.layout import BUILD_JSON, FORMATS
from appdgen.errors import AppdgenError
from appdgen.sources.recordings import CHANNELS
from appdgen.synth.recording import KINDS as RECORDING_KINDS
from appdgen.util.distribute import BACKENDS
from appdgen.util.sizes import parse_size

VERIFY_LINES = 20  # problems printed; the rest are counted


@main.command()
@calib_option
@camera_option
@images_option
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--samples", type=int, default=None, help="Total samples [default: 10 per image].")
@click.option("--per-image", type=int, default=None, help="Samples per raw image (instead of --samples).")
@size_option
@click.option("--format", "image_format", default="png", type=click.Choice(list(FORMATS)), show_default=True,
              help="Image encoding in the shards (png: compression level 1; npy: uint8 HxWx3 BGR, HxW grey).")
@click.option("--encoder", default=None, type=click.Choice(list(ENCODERS)),
              help="PNG encoder: libdeflate (3-4x faster than OpenCV's level 1, same size, grey and colour), "
                   "opencv (libpng level 1: the bytes of builds before --encoder) or fpng (faster still, files ~9 % "
                   "larger, colour only; pip install 'appdgen[fpng]'). Same bytes on any machine for each; "
                   f"recorded in {BUILD_JSON}. See docs/performance.md. [default: {DEFAULT_ENCODER}; with "
                   "--resume, the interrupted build's]")
@click.option("--shard-size", type=int, default=None,
              help="Samples per shard [default: from --samples alone, about 64 shards of 8 to 1000 samples].")
@click.option("--jobs", type=int, default=None,
              help="Worker processes, as joblib's n_jobs: -1 all cores, -2 all but one, … [default: all cores].")
@click.option("--seed", default=0, show_default=True, help="Build seed: the same seed gives the same bytes.")
@sampling_options
@split_by_option
@click.option("--skip-bad", is_flag=True,
              help="Skip images (or frames) of the wrong size, truncated, unreadable or with alpha channels, listing "
                   f"each in {BUILD_JSON} (else the first is an error).")
@recording_options
@click.option("--channels", "channels_choice", default="auto", type=click.Choice(CHANNELS), show_default=True,
              help="Channels of the samples: 1 grey, 3 BGR; auto: 1 when every source image is grey (mono8, "
                   "mono16, grey PNG), else 3.")
@click.option("--resume", is_flag=True,
              help="Finish an interrupted build in --out (same options, same calibration and image files; "
                   "any working folder).")
@click.option("--overwrite", is_flag=True, help="Replace a previous build in --out.")
@click.option("--backend", default="loky", type=click.Choice(list(BACKENDS)), show_default=True,
              help="Parallel backend: local processes (loky) or a Dask cluster.")
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler address, e.g. tcp://host:8786.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@fail_cleanly
def build(calib_path, camera, images_spec, out_dir, samples, per_image, size, image_format, encoder, shard_size, jobs,
          seed,
          ranges, appd_max, zero_fraction, max_fov, interp, split_by, skip_bad, topic, every, min_interval, start, end,
          channels_choice, resume, overwrite, backend, scheduler, quiet):
    """Generate rectified samples with APPD labels: WebDataset shards + labels.parquet + build.json."""
    from appdgen.dataset.build import build as run_build
    from appdgen.dataset.folder import recorded_encoder
    from appdgen.dataset.plan import BuildConfig
    from appdgen.sampling.options import SamplingOptions
    from appdgen.sources.inputs import resolve_inputs
    from appdgen.sources.recordings import FrameChoice, resolve_channels
    from appdgen.util.distribute import resolve_jobs

    if samples is not None and per_image is not None:
        raise AppdgenError("give --samples or --per-image, not both")
    if resume and overwrite:
        raise AppdgenError("give --resume or --overwrite, not both")
    if per_image is not None and per_image < 1:
        raise AppdgenError(f"--per-image {per_image}: must be at least 1")
    workers = resolve_jobs(jobs)
    if encoder is None:  # a resumed PNG build goes on with the encoder its plan names, whatever today's default
        resumed = recorded_encoder(Path(out_dir)) if resume and image_format == "png" else None
        encoder = resumed or DEFAULT_ENCODER
    inputs = resolve_inputs(images_spec, calib_path, camera, split_by, topic,
                            FrameChoice(every, min_interval, start, end), skip_bad,
                            check_grey=channels_choice == "auto")
    reference, images, skipped = inputs.reference, inputs.images, inputs.skipped
    total = samples if samples is not None else len(images) * (per_image if per_image is not None else 10)
    config = BuildConfig(
        reference=reference, camera=inputs.camera, calib_path=calib_path, images=images, samples=total,
        size=parse_size(size) or reference.size, image_format=image_format, shard_size=shard_size, seed=seed,
        **SamplingOptions.parse(reference, ranges, appd_max, zero_fraction, max_fov, interp).build_fields(reference),
        channels=resolve_channels(channels_choice, inputs.mono), recordings=inputs.recordings, encoder=encoder,
    )
    if workers > config.shard_count and not quiet:
        click.echo(f"note: {config.shard_count} shard(s) for --jobs {workers}: a shard is one worker's work, so at "
                   f"most {config.shard_count} run (a smaller --shard-size spreads the build)", err=True)
    summary = run_build(config, Path(out_dir), workers, backend, scheduler, resume, overwrite,
                        progress=not quiet, command=["appdgen", *sys.argv[1:]], skipped=skipped)
    t = summary["timings"]
    skipped_note = f", {len(skipped)} images skipped (listed in {BUILD_JSON})" if skipped else ""
    click.echo(f"built {total} samples in {config.shard_count} shards ({t['shards_built']} now, {t['shards_resumed']} "
               f"resumed) in {t['wall_seconds']:.1f} s: {t['samples_per_second'] or 0:.1f} samples/s, "
               f"{t['mb_written']:.1f} MB written{skipped_note} -> {out_dir}")


@main.command()
@click.option("--calib", "calib_path", default=None, type=click.Path(dir_okay=False),
              help="Calibration file [default: the bundled KITTI 2011_09_26 file, camera 02].")
@camera_option
@click.option("--frames", type=int, required=True, help="Number of frames to render.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--seed", default=0, show_default=True, help="Scene seed: frame i depends on (seed, i) only.")
@click.option("--scale", default=1.0, show_default=True,
              help="Render a smaller camera: size and K scaled, distortion unchanged (0.25 → 348x128 for KITTI).")
@click.option("--mount", default="car", type=click.Choice(["car", "loose"]), show_default=True,
              help="Camera pose spread: car (lane keeping and suspension: yaw σ 0.01 rad, pitch ±0.008, roll "
                   "±0.005, height 1.65±0.03 m) or loose (yaw σ 0.12, pitch ±0.05, roll ±0.035, height 1.4-2.1 m).")
@click.option("--offset", default=0.0, show_default=True, metavar="METRES",
              help="Move every frame's camera sideways (along its x axis, + = right) after the scene is drawn: the "
                   "same streets from a new viewpoint (same --seed), as a stereo rig's other camera sees them.")
@click.option("--jobs", type=int, default=None,
              help="Worker processes, as build's --jobs (-1 all cores, -2 all but one, …) [default: all cores]; any "
                   "N, same bytes.")
@click.option("--as", "kind", default="png", type=click.Choice(["png", *RECORDING_KINDS]), show_default=True,
              help="Write the frames as PNGs, or as a robot's recording: a ROS 1 bag (recording.bag), a ROS 2 bag "
                   "folder with mcap or sqlite3 storage (recording/), or an mp4 video (recording.mp4); bags hold "
                   "sensor_msgs/Image on /cam0/image_raw at 10 Hz.")
@click.option("--mono", is_flag=True, help="Grey frames (mono8 in a bag), as a monochrome camera's.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@fail_cleanly
def synth(calib_path, camera, frames, out_dir, seed, scale, mount, offset, jobs, kind, mono, quiet):
    """Render procedural street frames as the (scaled) camera sees them, through any lens model, plus its
    calibration (calibration.yaml; calibration.json for ds/eucm, which OpenCV YAML cannot hold)."""
    from appdgen.calib.defaults import DEFAULT_CALIB_PATH
    from appdgen.calib.formats import save
    from appdgen.synth import MOUNTS, calibration_name, scale_calibration, synthesize
    from appdgen.synth.recording import frames_as, recording_target
    from appdgen.util.distribute import resolve_jobs
    from appdgen.util.progress import Progress

    if frames < 1:
        raise AppdgenError(f"--frames {frames}: must be at least 1")
    if not 0 < scale <= 4:
        raise AppdgenError(f"--scale {scale}: must be in (0, 4]")
    calib = load_calibration(calib_path or str(DEFAULT_CALIB_PATH), camera or (None if calib_path else "02"))
    scaled = scale_calibration(calib, scale)
    out = Path(out_dir)
    if kind != "png":
        recording_target(out, kind)  # refused before any frame is rendered
    bar = Progress(frames, unit="frames", enabled=not quiet)
    written = synthesize(calib, frames, out, seed, scale, progress=bar.advance, jobs=resolve_jobs(jobs),
                         mount=dataclasses.replace(MOUNTS[mount], offset=offset))
    where = frames_as(written, out, kind, mono)
    name = calibration_name(scaled)
    save(scaled, out / name)
    what = "" if kind == "png" else f" as {where.name}"
    click.echo(f"wrote {frames} frames ({scaled.width}x{scaled.height}){what} and {name} to {out_dir}")


@main.command("inspect")
@click.argument("out_dir", metavar="OUT", type=click.Path(file_okay=False))
@click.option("--sheet", default=None, type=click.Path(dir_okay=False),
              help="Also write a contact sheet PNG of samples spread over the APPD range.")
@click.option("--count", default=24, show_default=True, help="Samples on the contact sheet.")
@fail_cleanly
def inspect_command(out_dir, sheet, count):
    """Summarise a finished build: counts, splits, APPD histogram, sampler speed, size on disk."""
    from appdgen.dataset.images import write_image
    from appdgen.dataset.inspect import contact_sheet, summary

    click.echo(summary(Path(out_dir)))
    if sheet is not None:
        image = contact_sheet(Path(out_dir), count)
        write_image(Path(sheet), image)
        click.echo(f"wrote {sheet} ({image.shape[1]}x{image.shape[0]})")


@main.command("verify")
@click.argument("out_dir", metavar="OUT", type=click.Path(file_okay=False))
@fail_cleanly
def verify_command(out_dir):
    """Re-read every shard and check it against labels.parquet and build.json (exit 1 on any mismatch)."""
    from appdgen.dataset.verify import verify

    report = verify(Path(out_dir))
    checked = f"{report.samples} samples in {report.shard_count} shards"
    for note in report.notes:
        click.echo(f"note: {note}", err=True)
    if report.ok:
        click.echo(f"verified {checked}: OK")
        return
    for line in report.problems[:VERIFY_LINES]:
        click.echo(line)
    if report.total > VERIFY_LINES:
        click.echo(f"… and {report.total - VERIFY_LINES} more")
    noun = "problem" if report.total == 1 else "problems"
    click.echo(f"verify failed: {report.total} {noun} in {checked} ({out_dir})", err=True)
    sys.exit(1)


@main.command()
@click.argument("kitti_root", required=False, type=click.Path(file_okay=False))
@click.option("--camera", default="02", show_default=True, help="KITTI camera: lists image_<camera>/data/*.png.")
@click.option("--split-file", default=None, type=click.Path(dir_okay=False),
              help="'DRIVE SPLIT' / 'DAY SPLIT' lines, e.g. manifests/kitti_raw_split.txt [default: split = day].")
@click.option("--nuscenes", "nuscenes_root", default=None, type=click.Path(file_okay=False),
              help="List a nuScenes tree instead: ROOT/samples/<channel>/*.jpg.")
@click.option("--channel", default="CAM_FRONT", show_default=True, help="nuScenes camera channel.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="List file; for KITTI one list per day: kitti_02.txt -> kitti_02_<day>.txt.")
@fail_cleanly
def manifest(kitti_root, camera, split_file, nuscenes_root, channel, output):
    """Write image lists ('PATH SPLIT' lines) for build --images from a local KITTI raw or nuScenes tree."""
    from appdgen.sources.manifest import kitti_manifests, nuscenes_manifest

    if (kitti_root is None) == (nuscenes_root is None):
        raise AppdgenError("give a KITTI_ROOT or --nuscenes ROOT (one of them)")
    if nuscenes_root is not None:
        count = nuscenes_manifest(Path(nuscenes_root), channel, Path(output))
        click.echo(f"{count} images -> {output} (split 'all'; build with the calibrated_sensor record of the car "
                   f"that recorded them)")
        return
    for day in kitti_manifests(Path(kitti_root), camera, Path(output), Path(split_file) if split_file else None):
        splits = ", ".join(f"{name} {n}" for name, n in day.splits.items())
        drives = f"{day.drives} drive" + ("s" if day.drives != 1 else "")
        click.echo(f"{day.day}: {drives}, {day.images} images ({splits}) -> {day.path}")
        if not day.calibration.is_file():
            click.echo(f"  warning: {day.calibration} is missing (sizes not checked); get the day's calibration "
                       f"before building", err=True)
        click.echo(f"  appdgen build --calib {day.calibration} --camera {day.camera} --images {day.path} "
                   f"--out OUT_{day.day}")
