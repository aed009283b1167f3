"""The `appdgen` command line: thin click commands over the library."""
from __future__ import annotations

import csv
import functools
import io
import json
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import IO, Any, Callable

import click
import numpy as np

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
json_option = click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
csv_option = click.option("--csv", "csv_path", default=None, type=click.Path(dir_okay=False),
                          help="Also write the numbers to this CSV file.")
plot_option = click.option("--plot", "plot_path", default=None, type=click.Path(dir_okay=False),
                           help="Also draw a figure to this PNG file (needs the 'plot' extra: matplotlib).")


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
@json_option
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


# --- analyses (issue #7): sweep, reproj, drift ---------------------------------------------------------------------


def format_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table: first column left-aligned, the others right-aligned to their widest cell."""
    cells = [list(header), *map(list, rows)]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    return "\n".join("  ".join(cell.ljust(w) if i == 0 else cell.rjust(w)
                                for i, (cell, w) in enumerate(zip(row, widths))) for row in cells)


def write_csv(path: str, header: Sequence[str], rows: Iterable[Sequence[object]]) -> None:
    """Write a CSV file atomically: numbers at full precision, NaN as 'nan'."""
    from appdgen.atomic import write_file

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    write_file(Path(path), buffer.getvalue().encode("utf-8"))


def note(text: str) -> None:
    """A remark about the results, on stderr so that stdout stays the results."""
    click.echo(f"note: {text}", err=True)


def describe_source(path: str, camera: str | None) -> str:
    """'<folder>/<file>' and the camera, for titles."""
    where = "/".join(Path(path).resolve().parts[-2:])
    return f"{where} camera {camera}" if camera else where


def start_plot(plot_path: str | None) -> None:
    """Fail before the computation, not after it, when --plot is asked without matplotlib."""
    if plot_path:
        from appdgen.plots import require

        require()


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


@main.command()
@click.option("--calib", "calib_path", default=None, type=click.Path(dir_okay=False),
              help="Calibration file [default: the bundled KITTI 2011_09_26 file, camera 02].")
@camera_option
@click.option("--frames", type=int, required=True, help="Number of frames to render.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder.")
@click.option("--seed", default=0, show_default=True, help="Scene seed: frame i depends on (seed, i) only.")
@click.option("--scale", default=1.0, show_default=True,
              help="Render a smaller camera: size and K scaled, distortion unchanged (0.25 → 348x128 for KITTI).")
@click.option("--quiet", is_flag=True, help="No progress line.")
@fail_cleanly
def synth(calib_path, camera, frames, out_dir, seed, scale, quiet):
    """Render procedural street frames as the (scaled) camera sees them, plus its calibration.yaml."""
    from appdgen.defaults import DEFAULT_CALIB_PATH
    from appdgen.formats import save
    from appdgen.progress import Progress
    from appdgen.synth import scale_calibration, synthesize

    if frames < 1:
        raise AppdgenError(f"--frames {frames}: must be at least 1")
    if not 0 < scale <= 4:
        raise AppdgenError(f"--scale {scale}: must be in (0, 4]")
    calib = load_calibration(calib_path or str(DEFAULT_CALIB_PATH), camera or (None if calib_path else "02"))
    scaled = scale_calibration(calib, scale)
    out = Path(out_dir)
    bar = Progress(frames, unit="frames", enabled=not quiet)
    synthesize(calib, frames, out, seed, scale, progress=bar.advance)
    save(scaled, out / "calibration.yaml")
    click.echo(f"wrote {frames} frames ({scaled.width}x{scaled.height}) and calibration.yaml to {out_dir}")


@main.command()
@calib_option
@camera_option
@click.option("--params", default=",".join(PARAMS), show_default=True,
              help="Comma-separated parameters, each swept alone.")
@click.option("--from", "start", type=float, default=-0.2, show_default=True,
              help="First fraction t: value x (1 + t).")
@click.option("--to", "stop", type=float, default=0.2, show_default=True, help="Last fraction t.")
@click.option("--steps", type=int, default=101, show_default=True,
              help="Number of t values, evenly spaced, ends included.")
@size_option
@csv_option
@plot_option
@fail_cleanly
def sweep(calib_path, camera, params, start, stop, steps, size, csv_path, plot_path):
    """APPD as each parameter alone is multiplied by (1 + t), the others fixed (the paper's per-parameter figure).

    APPD, in % of the raw diagonal, is against the unperturbed calibration. Parameters equal to 0 are skipped
    (multiplying 0 changes nothing); t values giving an invalid calibration (distortion folding over, focal
    length <= 0) give NaN and are counted on stderr. Prints t against APPD at five t values; --csv has them all.
    The default output size is the raw size, for fidelity; a quarter of it per side (--size 348x128 for KITTI)
    runs about 3 times faster and moves KITTI's APPD by under 0.0001 % of the diagonal.
    """
    from appdgen.analysis import sweep as sweep_appd, sweep_fractions

    start_plot(plot_path)
    calib = load_calibration(calib_path, camera)
    names = list(dict.fromkeys(n.strip() for n in params.split(",") if n.strip()))
    t = sweep_fractions(start, stop, steps)
    out_size = parse_size(size)
    curves = sweep_appd(calib, names, t, out_size)
    for name in names:
        if name not in curves:
            note(f"{name} skipped: it is 0 in this calibration, and multiplying 0 changes nothing")
        elif np.isnan(curves[name]).any():
            note(f"{name}: {np.isnan(curves[name]).sum()} of {len(t)} t values give an invalid calibration (NaN)")
    w, h = out_size or calib.size
    click.echo(f"APPD (% of the {calib.diagonal:.1f} px diagonal) with one parameter x (1 + t), others fixed: "
               f"{describe_source(calib_path, camera)}, output {w}x{h}")
    shown = np.unique(np.round(np.linspace(0, len(t) - 1, 5)).astype(int))
    click.echo(format_table(["t", *curves], [[f"{100 * t[i]:+.1f} %", *(f"{curves[n][i]:.4f}" for n in curves)]
                                             for i in shown]))
    if csv_path:
        write_csv(csv_path, ["t", *(f"appd_pct_{n}" for n in curves)],
                  ([float(ti), *(float(curves[n][i]) for n in curves)] for i, ti in enumerate(t)))
    if plot_path:
        from appdgen.plots import plot_sweep

        plot_sweep(Path(plot_path), t, curves, f"APPD as one parameter changes, others fixed: "
                   f"{describe_source(calib_path, camera)} (output {w}x{h})", calib.diagonal)


@main.command()
@calib_option
@camera_option
@click.option("--samples", type=int, default=500, show_default=True, help="Valid calibrations Θm to sample.")
@click.option("--scenario", type=click.Choice(["synthetic", "physical", "both"]), default="both", show_default=True,
              help="Which reprojection error: (a) synthetic, (b) physical, or both on the same Θm.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (points, then calibrations).")
@click.option("--points", type=int, default=1000, show_default=True, help="3-D points per calibration.")
@size_option
@csv_option
@plot_option
@fail_cleanly
def reproj(calib_path, camera, samples, scenario, seed, points, size, csv_path, plot_path):
    """APPD against reprojection error for calibrations Θm sampled around the file's Θ* (the paper's scatter figure).

    Θm = Θ* x (1 + t), with t uniform per parameter in the paper's ranges: fx, fy -5..+20 %, cx, cy +-5 %,
    k1, k2, p1, p2, k3 +-15 %; draws whose distortion folds over are skipped and counted. The 3-D points are
    seen uniformly over Θ*'s rectified view (a projection depends only on X/Z, so depth changes nothing).
    Per Θm, the reprojection error is the mean over the points of:

    \b
    synthetic (a): Θ*'s raw projection rectified with Θm (undistort with Θm,
                   then K̂(Θm)), against the same raw point rectified with Θ*,
                   which is K̂(Θ*)·X/Z;
    physical (b):  the camera drifted to Θm: its raw projection rectified with
                   Θ* (undistort with Θ*, then K̂(Θ*)), against the ideal
                   projection K̂(Θ*)·X/Z; only the points that Θm projects
                   inside the raw frame count.

    Errors are in pixels of the rectified output (--size, default the raw size); APPD is in % of the raw
    diagonal. Prints Spearman's rank correlation between APPD and each scenario's error.
    """
    from appdgen.analysis import SCENARIOS, reprojection_study, spearman

    start_plot(plot_path)
    calib = load_calibration(calib_path, camera)
    scenarios = SCENARIOS if scenario == "both" else (scenario,)
    study = reprojection_study(calib, samples, scenarios, seed, parse_size(size), points)
    source = describe_source(calib_path, camera)
    click.echo(f"{source}: {samples} calibrations sampled in the paper's ranges ({study.skipped} invalid draws "
               f"skipped), {points} points, seed {seed}, output {study.size[0]}x{study.size[1]}")
    click.echo(f"APPD: {np.min(study.appd_pct):.3f} .. {np.max(study.appd_pct):.3f} % of the diagonal "
               f"(median {np.median(study.appd_pct):.3f} %)")
    for name, error in study.reproj_px.items():
        click.echo(f"{name}: reprojection error {np.nanmin(error):.2f} .. {np.nanmax(error):.2f} px (median "
                   f"{np.nanmedian(error):.2f} px); Spearman rho(APPD, error) = {spearman(study.appd_pct, error):.3f}")
    if csv_path:
        header = ["sample", *(f"t_{p}" for p in PARAMS), "appd_px", "appd_pct", *(f"reproj_{n}_px" for n in scenarios)]
        write_csv(csv_path, header, ([i, *study.fractions[i].tolist(), study.appd_px[i], study.appd_pct[i],
                                      *(study.reproj_px[n][i] for n in scenarios)] for i in range(samples)))
    if plot_path:
        from appdgen.plots import plot_reproj

        plot_reproj(Path(plot_path), study, f"APPD against reprojection error: {samples} calibrations sampled around {source}")


def file_labels(paths: Sequence[str]) -> list[str]:
    """File names; the parent folder's name for files sharing a base name (KITTI <day>/calib_cam_to_cam.txt)."""
    names = [Path(p).name for p in paths]
    labels = [Path(p).resolve().parent.name if names.count(n) > 1 else n for p, n in zip(paths, names)]
    return labels if len(set(labels)) == len(labels) else list(paths)


def common_cameras(paths: Sequence[str]) -> list[str]:
    """The camera names every file has, in the first file's order."""
    from appdgen.formats import list_cameras

    listed = [list_cameras(Path(p)) for p in paths]
    common = [name for name in listed[0] if all(name in other for other in listed[1:])]
    if not common:
        raise AppdgenError("the files have no camera name in common; choose one with --camera")
    return common


def rounding_note(labels: Sequence[str], calibs: Sequence[Calibration], size: tuple[int, int] | None) -> str | None:
    """A note naming calibrations with at most 3 significant digits, with the APPD that such rounding alone gives."""
    from appdgen.analysis import round_significant
    from appdgen.appd import appd_px
    from appdgen.maps import rectify as rectify_calibration

    rounded = [label for label, c in zip(labels, calibs) if round_significant(c, 3) == c]
    full = [(label, c) for label, c in zip(labels, calibs) if label not in rounded]
    if not rounded:
        return None
    text = f"{', '.join(rounded)}: values have at most 3 significant digits, so part of their APPD is rounding"
    if full:
        label, c = full[0]
        floor = appd_px(rectify_calibration(c, size), rectify_calibration(round_significant(c, 3), size))
        text += f" (rounding {label} to 3 digits alone gives {floor:.2f} px)"
    return text


@main.command()
@click.argument("calib_paths", nargs=-1, required=True, type=click.Path(dir_okay=False), metavar="CALIB...")
@click.option("--camera", "cameras", multiple=True,
              help="Camera to compare, e.g. 02 (repeatable; default: every camera that all files have).")
@size_option
@json_option
@plot_option
@fail_cleanly
def drift(calib_paths, cameras, size, as_json, plot_path):
    """APPD between the same camera's calibrations in several files, e.g. KITTI's recording days.

    For each camera, prints the symmetric matrix of APPD between every pair of files, in raw px and in % of
    the raw diagonal. Files are labelled by their name, or by their folder's name where files share a name
    (KITTI's <day>/calib_cam_to_cam.txt). Files whose values all have at most 3 significant digits (the reduced
    KITTI days) are noted on stderr with the APPD that such rounding alone causes.
    """
    start_plot(plot_path)
    labels = file_labels(calib_paths)
    out_size = parse_size(size)
    tables = {camera: drift_table(calib_paths, labels, camera, out_size)
              for camera in cameras or common_cameras(calib_paths)}
    if as_json:
        click.echo(json.dumps({"files": list(calib_paths), "labels": labels, "cameras": {
            camera: {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in table.items()}
            for camera, table in tables.items()}}, indent=2))
    else:
        for camera, table in tables.items():
            echo_drift(camera, table, labels)
    if plot_path:
        from appdgen.plots import plot_drift

        w, h = next(iter(tables.values()))["size"]
        plot_drift(Path(plot_path), {cam: (labels, t["appd_px"], t["diagonal_px"]) for cam, t in tables.items()},
                   f"APPD between calibrations of the same camera (output {w}x{h}; cells: raw px and % of diagonal)")


def drift_table(paths: Sequence[str], labels: Sequence[str], camera: str, size: tuple[int, int] | None) -> dict:
    """One camera's APPD matrix between the files (raw px and %), its output size and diagonal, a rounding note."""
    from appdgen.analysis import drift_matrix

    calibs = [load_calibration(p, camera) for p in paths]
    matrix = drift_matrix(calibs, size, labels)
    diagonal = calibs[0].diagonal
    return {"size": list(size or calibs[0].size), "diagonal_px": diagonal, "appd_px": matrix,
            "appd_pct": matrix * 100 / diagonal, "note": rounding_note(labels, calibs, size)}


def echo_drift(camera: str, table: dict, labels: Sequence[str]) -> None:
    """Print one camera's drift matrices, in raw px then in % of the diagonal, and its rounding note (stderr)."""
    w, h = table["size"]
    for key, unit in (("appd_px", "raw px"), ("appd_pct", f"% of the {table['diagonal_px']:.1f} px diagonal")):
        click.echo(f"camera {camera}: APPD in {unit} (output {w}x{h})")
        rows = [[label, *(f"{v:.3f}" for v in row)] for label, row in zip(labels, table[key])]
        click.echo(format_table(["", *labels], rows) + "\n")
    if table["note"]:
        note(f"camera {camera}: {table['note']}")

@main.command("inspect")
@click.argument("out_dir", metavar="OUT", type=click.Path(file_okay=False))
@click.option("--sheet", default=None, type=click.Path(dir_okay=False),
              help="Also write a contact sheet PNG of samples spread over the APPD range.")
@click.option("--count", default=24, show_default=True, help="Samples on the contact sheet.")
@fail_cleanly
def inspect_command(out_dir, sheet, count):
    """Summarise a finished build: counts, splits, APPD histogram, sampler speed, size on disk."""
    from appdgen.images import write_image
    from appdgen.inspection import contact_sheet, summary

    click.echo(summary(Path(out_dir)))
    if sheet is not None:
        image = contact_sheet(Path(out_dir), count)
        write_image(Path(sheet), image)
        click.echo(f"wrote {sheet} ({image.shape[1]}x{image.shape[0]})")


VERIFY_LINES = 20  # problems printed; the rest are counted


@main.command("verify")
@click.argument("out_dir", metavar="OUT", type=click.Path(file_okay=False))
@fail_cleanly
def verify_command(out_dir):
    """Re-read every shard and check it against labels.parquet and build.json (exit 1 on any mismatch)."""
    from appdgen.inspection import verify

    report = verify(Path(out_dir))
    checked = f"{report.samples} samples in {report.shards} shards"
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
    from appdgen.manifest import kitti_manifests, nuscenes_manifest

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


if __name__ == "__main__":
    main()
