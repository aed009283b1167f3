"""The `appdgen` command line: thin click commands over the library."""
from __future__ import annotations

import functools
import json
import sys
from pathlib import Path
from typing import IO, Any, Callable

import click

from appdgen import __version__
from appdgen.calibration import PARAMS, Calibration
from appdgen.errors import AppdgenError


def fail_cleanly(command: Callable) -> Callable:
    """Turn AppdgenError into one line on stderr and exit status 2 (no traceback)."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except AppdgenError as error:
            click.echo(f"appdgen: error: {' '.join(str(error).splitlines())}", err=True)  # a path may hold a newline
            sys.exit(2)

    return wrapper


class OneLineUsageError(click.ClickException):
    """A bad or missing option, shown as one line like AppdgenError (exit status 2, as click's own)."""

    exit_code = 2

    def show(self, file: IO[Any] | None = None) -> None:
        """Print `appdgen: error: …` on stderr."""
        click.echo(f"appdgen: error: {' '.join(self.format_message().splitlines())}", err=True)


class AppdgenGroup(click.Group):
    """The command group: a subcommand's usage errors become one line instead of click's usage block."""

    def invoke(self, ctx: click.Context) -> Any:
        """Run the subcommand, turning click.UsageError into OneLineUsageError."""
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:
            where = exc.ctx.command_path if exc.ctx else "appdgen"
            raise OneLineUsageError(f"{exc.format_message()} (see '{where} --help')") from None


def parse_size(text: str | None) -> tuple[int, int] | None:
    """'WxH' → (W, H) in pixels; None passes through."""
    if text is None:
        return None
    try:
        w, h = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise AppdgenError(f"--size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 348x128") from None
    if w <= 0 or h <= 0:
        raise AppdgenError(f"--size {text!r}: width and height must be positive")
    return w, h


def parse_assignments(option: str, items: tuple[str, ...]) -> dict[str, float]:
    """('fx=0.05', …) → {'fx': 0.05, …}, checking names against the nine parameters."""
    values: dict[str, float] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or name not in PARAMS:
            raise AppdgenError(f"{option} {item!r}: expected NAME=VALUE with NAME one of {', '.join(PARAMS)}")
        try:
            values[name] = float(text)
        except ValueError:
            raise AppdgenError(f"{option} {item!r}: {text!r} is not a number") from None
    return values


def load_calibration(path: str, camera: str | None) -> Calibration:
    """Read a calibration file of any supported format (errors name the file)."""
    from appdgen.formats import load

    return load(Path(path), camera=camera)


def modified(calib: Calibration, sets: tuple[str, ...], perturbs: tuple[str, ...]) -> Calibration:
    """Apply --set NAME=VALUE (absolute) then --perturb NAME=FRACTION (× (1 + fraction))."""
    calib = calib.replace(**parse_assignments("--set", sets))
    return calib.perturb(**parse_assignments("--perturb", perturbs))


calib_option = click.option("--calib", "calib_path", required=True, type=click.Path(dir_okay=False),
                            help="Calibration file (KITTI, OpenCV YAML/XML, ROS, Kalibr, nuScenes, appdgen JSON).")
camera_option = click.option("--camera", default=None, help="Camera in the file, e.g. 02 for KITTI image_02.")
set_option = click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
                          help="Set a parameter to an absolute value (repeatable).")
perturb_option = click.option("--perturb", "perturbs", multiple=True, metavar="NAME=FRACTION",
                              help="Multiply a parameter by (1 + FRACTION), e.g. fx=0.05 (repeatable).")
size_option = click.option("--size", default=None, metavar="WxH",
                           help="Output size in pixels (default: the raw size; must keep the raw aspect).")


@click.group(cls=AppdgenGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="appdgen")
def main() -> None:
    """Self-labelled data for learning camera miscalibration detection (APPD labels)."""


def _describe(calib: Calibration, new_k) -> dict:
    """A calibration's parameters, size and output camera matrix K̂, JSON-ready."""
    return {**calib.params(), "size": list(calib.size), "new_camera_matrix": new_k.tolist()}


@main.command()
@calib_option
@camera_option
@set_option
@perturb_option
@click.option("--against", "against_path", default=None, type=click.Path(dir_okay=False),
              help="Compare with this second calibration file instead of a perturbation.")
@click.option("--against-camera", default=None, help="Camera in the --against file (default: --camera).")
@size_option
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
@fail_cleanly
def appd(calib_path, camera, sets, perturbs, against_path, against_camera, size, as_json):
    """APPD between a reference calibration and a perturbed (or second) one."""
    from appdgen.appd import appd_px, px_to_pct
    from appdgen.maps import rectify

    reference = load_calibration(calib_path, camera)
    other = load_calibration(against_path, against_camera or camera) if against_path else reference
    other = modified(other, sets, perturbs)
    if other.size != reference.size:
        raise AppdgenError(f"{against_path}: raw size {other.size} differs from {calib_path}'s {reference.size}")
    out_size = parse_size(size)
    ref_rect, other_rect = rectify(reference, out_size), rectify(other, out_size)
    value = appd_px(ref_rect, other_rect)
    result = {
        "appd_px": value,
        "appd_pct": px_to_pct(value, reference),
        "size": list(ref_rect.size),
        "reference": _describe(reference, ref_rect.new_camera_matrix),
        "perturbed": _describe(other, other_rect.new_camera_matrix),
    }
    if as_json:
        click.echo(json.dumps(result, indent=2))
    else:
        click.echo(f"APPD {value:.4f} px = {result['appd_pct']:.4f} % of the {reference.diagonal:.1f} px diagonal "
                   f"(output {ref_rect.size[0]}x{ref_rect.size[1]})")


@main.command()
@calib_option
@camera_option
@set_option
@perturb_option
@size_option
@click.option("--interp", default="lanczos4", type=click.Choice(["nearest", "linear", "cubic", "lanczos4"]),
              show_default=True, help="Interpolation of the remap.")
@click.argument("image", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output image (PNG, JPG…).")
@fail_cleanly
def rectify(calib_path, camera, sets, perturbs, size, interp, image, output):
    """Rectify, crop and rescale one raw image with a (perturbed) calibration."""
    from appdgen.images import read_image, write_image
    from appdgen.maps import rectify as rectify_calibration
    from appdgen.render import remap_image

    calib = modified(load_calibration(calib_path, camera), sets, perturbs)
    rect = rectify_calibration(calib, parse_size(size))
    write_image(Path(output), remap_image(read_image(Path(image)), rect, interp))
    click.echo(f"wrote {output} ({rect.size[0]}x{rect.size[1]})")


def choose_camera(calib_path: str, camera: str | None, images) -> str:
    """--camera, else the KITTI image_0X folder, else the only camera whose size matches the images."""
    from appdgen.formats import list_cameras
    from appdgen.sources import image_size, kitti_camera

    if camera is not None:
        return camera
    cameras = list_cameras(Path(calib_path))
    if len(cameras) == 1:
        return cameras[0]
    named = kitti_camera(images)
    if named is not None and named in cameras:
        return named
    size = image_size(images[0].path)
    fitting = [c for c in cameras if load_calibration(calib_path, c).size == size]
    if len(fitting) == 1:
        return fitting[0]
    if not fitting:
        raise AppdgenError(f"{calib_path}: no camera ({', '.join(cameras)}) is {size[0]}x{size[1]} like "
                           f"{images[0].path}")
    raise AppdgenError(f"{calib_path}: cameras {', '.join(fitting)} fit the images; choose one with --camera")


@main.command()
@calib_option
@camera_option
@click.option("--images", "images_spec", required=True,
              help="Raw images: a folder (recursive), a glob pattern, or a list file ('PATH [SPLIT]' per line).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--samples", type=int, default=None, help="Total samples [default: 10 per image].")
@click.option("--per-image", type=int, default=None, help="Samples per raw image (instead of --samples).")
@size_option
@click.option("--format", "image_format", default="png", type=click.Choice(["png", "jpg", "npy"]), show_default=True,
              help="Image encoding in the shards (png: compression level 1).")
@click.option("--shard-size", default=1000, show_default=True, help="Samples per shard.")
@click.option("--jobs", type=int, default=None, help="Parallel workers [default: all cores].")
@click.option("--seed", default=0, show_default=True, help="Build seed: the same seed gives the same bytes.")
@click.option("--ranges", default=None, metavar="NAME=LO:HI,...",
              help="Override ranges: '%' bounds are relative to the reference (fx=-5%:20%), bare ones absolute "
                   "(k3=-0.01:0.01). Defaults: focal -5%:20%, principal point -5%:5%, distortion -15%:15%.")
@click.option("--appd-max", default=1.0, show_default=True, help="Largest APPD label, % of the raw diagonal.")
@click.option("--zero-fraction", default=0.01, show_default=True, help="Fraction of samples that are exactly Θ*.")
@click.option("--interp", default="lanczos4", type=click.Choice(["nearest", "linear", "cubic", "lanczos4"]),
              show_default=True, help="Interpolation of the remap.")
@click.option("--split-by", default="none", type=click.Choice(["none", "parent", "day", "drive"]), show_default=True,
              help="Split column from the path: first folder, KITTI day, or KITTI drive (list files may name splits).")
@click.option("--skip-bad", is_flag=True, help="Skip (and count) images of the wrong size or unreadable headers.")
@click.option("--resume", is_flag=True, help="Finish an interrupted build in --out (same inputs and options).")
@click.option("--overwrite", is_flag=True, help="Replace a previous build in --out.")
@click.option("--backend", default="loky", type=click.Choice(["loky", "dask"]), show_default=True,
              help="Parallel backend: local processes (loky) or a Dask cluster.")
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler address, e.g. tcp://host:8786.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@fail_cleanly
def build(calib_path, camera, images_spec, out_dir, samples, per_image, size, image_format, shard_size, jobs, seed,
          ranges, appd_max, zero_fraction, interp, split_by, skip_bad, resume, overwrite, backend, scheduler, quiet):
    """Generate rectified samples with APPD labels: WebDataset shards + labels.parquet + build.json."""
    from appdgen.build import BuildConfig, build as run_build
    from appdgen.distribute import default_jobs
    from appdgen.sampling import parse_ranges
    from appdgen.sources import check_sizes, list_images

    if samples is not None and per_image is not None:
        raise AppdgenError("give --samples or --per-image, not both")
    if resume and overwrite:
        raise AppdgenError("give --resume or --overwrite, not both")
    if per_image is not None and per_image < 1:
        raise AppdgenError(f"--per-image {per_image}: must be at least 1")
    images = list_images(images_spec, split_by)
    camera = choose_camera(calib_path, camera, images)
    reference = load_calibration(calib_path, camera)
    images, skipped = check_sizes(images, reference.size, skip_bad)
    total = samples if samples is not None else len(images) * (per_image if per_image is not None else 10)
    config = BuildConfig(
        reference=reference, camera=camera, calib_path=calib_path, images=tuple(images), samples=total,
        size=parse_size(size) or reference.size, image_format=image_format, shard_size=shard_size, seed=seed,
        ranges=parse_ranges(ranges), appd_max=appd_max, zero_fraction=zero_fraction, interp=interp,
    )
    summary = run_build(config, Path(out_dir), jobs or default_jobs(), backend, scheduler, resume, overwrite,
                        progress=not quiet, command=["appdgen", *sys.argv[1:]], skipped=skipped)
    t = summary["timings"]
    skipped_note = f", {len(skipped)} images skipped" if skipped else ""
    click.echo(f"built {total} samples in {config.shards} shards ({t['shards_built']} now, {t['shards_resumed']} "
               f"resumed) in {t['wall_seconds']:.1f} s: {t['samples_per_second'] or 0:.1f} samples/s, "
               f"{t['mb_written']:.1f} MB written{skipped_note} -> {out_dir}")


if __name__ == "__main__":
    main()
