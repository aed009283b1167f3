"""The `appdgen` command group and what its commands share: one-line errors, option parsers, common options."""
from __future__ import annotations

import csv
import functools
import io
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import IO, Any, Callable

import click

from appdgen.calib.calibration import Calibration
from appdgen.errors import AppdgenError
from appdgen.geometry.remap import DEFAULT_INTERP, INTERPOLATIONS
from appdgen.version import __version__


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


def parse_assignments(option: str, items: tuple[str, ...], calib: Calibration) -> dict[str, float]:
    """('fx=0.05', …) → {'fx': 0.05, …}, checking names against calib's parameters (its lens model's)."""
    values: dict[str, float] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or name not in calib.param_names:
            raise AppdgenError(f"{option} {item!r}: expected NAME=VALUE with NAME one of "
                               f"{', '.join(calib.param_names)} (lens model {calib.model})")
        try:
            values[name] = float(text)
        except ValueError:
            raise AppdgenError(f"{option} {item!r}: {text!r} is not a number") from None
    return values


def load_calibration(path: str, camera: str | None) -> Calibration:
    """Read a calibration file of any supported format (errors name the file)."""
    from appdgen.calib.formats import load

    return load(Path(path), camera=camera)


def modified(calib: Calibration, sets: tuple[str, ...], perturbs: tuple[str, ...]) -> Calibration:
    """Apply --set NAME=VALUE (absolute) then --perturb NAME=FRACTION (× (1 + fraction))."""
    calib = calib.replace(**parse_assignments("--set", sets, calib))
    return calib.perturb(**parse_assignments("--perturb", perturbs, calib))


CALIB_HELP = ("Calibration file (KITTI, OpenCV YAML/XML, ROS, Kalibr, EuRoC, Basalt, nuScenes, appdgen JSON), any "
              "lens model.")
calib_option = click.option("--calib", "calib_path", required=True, type=click.Path(dir_okay=False), help=CALIB_HELP)

IMAGES_HELP = ("Raw images: a folder (recursive), a glob pattern, or a list file ('PATH [SPLIT]' per line, or "
               "'PATH<TAB>SPLIT' for paths with spaces; relative paths are read from the list's folder); or a "
               "recording: a ROS 1 .bag, a ROS 2 bag folder or .db3/.mcap file (appdgen[ros]), a video file "
               "(appdgen[video]).")
images_option = click.option("--images", "images_spec", required=True, help=IMAGES_HELP)


def split_by_option(command: Callable) -> Callable:
    """--split-by: the split column from each raw image's path (build's, and fit --online's holdout)."""
    from appdgen.sources.files import SPLIT_BY

    return click.option("--split-by", default="none", type=click.Choice(list(SPLIT_BY)), show_default=True,
                        help="Split column from the path: first folder, KITTI day, KITTI drive, or recording (each "
                             "bag or video; for images their folder); list files may name splits.")(command)


camera_option = click.option("--camera", default=None, help="Camera in the file, e.g. 02 for KITTI image_02.")


set_option = click.option("--set", "sets", multiple=True, metavar="NAME=VALUE",
                          help="Set a parameter (fx, fy, cx, cy or the lens model's) to an absolute value "
                               "(repeatable).")


perturb_option = click.option("--perturb", "perturbs", multiple=True, metavar="NAME=FRACTION",
                              help="Multiply a parameter by (1 + FRACTION), e.g. fx=0.05 (repeatable).")


#: Largest --max-fov accepted (degrees): the rectified image is a pinhole view, below 180° wide.
MAX_FOV_LIMIT = 180.0

max_fov_option = click.option(
    "--max-fov", "max_fov", default=None, metavar="DEG",
    type=click.FloatRange(0.0, MAX_FOV_LIMIT, min_open=True, max_open=True),
    help="Bound the rectified image's horizontal field of view to DEG degrees, for the reference and every "
         "perturbed calibration alike (default: unbounded, the largest valid crop).")


size_option = click.option("--size", default=None, metavar="WxH",
                           help="Output size in pixels (default: the raw size; must keep the raw aspect).")


interp_option = click.option("--interp", default=DEFAULT_INTERP, type=click.Choice(list(INTERPOLATIONS)),
                             show_default=True, help="Interpolation of the remap.")


def stack_options(command: Callable, options: list[Callable]) -> Callable:
    """Apply click option decorators to a command so that --help lists them in the given order."""
    for option in reversed(options):
        command = option(command)
    return command


def sampling_options(command: Callable) -> Callable:
    """--ranges, --appd-max, --zero-fraction, --max-fov and --interp (sampling.options.SamplingOptions): the same
    names, defaults and help for `appdgen build` and `python -m train fit --online`."""
    from appdgen.sampling.options import DEFAULT_ZERO_FRACTION
    from appdgen.sampling.sampler import DEFAULT_APPD_MAX

    options = [
        click.option("--ranges", default=None, metavar="NAME=LO:HI,...",
                     help="Override ranges of the lens model's parameters: '%' bounds are relative to the reference "
                          "(fx=-5%:20%), bare ones absolute (k3=-0.01:0.01). Defaults: focal -5%:20%, principal "
                          "point -5%:5%, non-zero coefficients -15%:15% (zero ones: none for radtan, see "
                          "docs/lens-models.md otherwise)."),
        click.option("--appd-max", default=DEFAULT_APPD_MAX, show_default=True,
                     help="Largest APPD label, % of the raw diagonal; refused up front when the ranges cannot reach "
                          "it."),
        click.option("--zero-fraction", default=DEFAULT_ZERO_FRACTION, show_default=True,
                     help="Fraction of samples that are exactly Θ*."),
        max_fov_option,
        interp_option,
    ]
    return stack_options(command, options)


def recording_options(command: Callable) -> Callable:
    """--topic, --every, --min-interval, --start, --end: which frames of a recording (build, predict, fit --online)."""
    return stack_options(command, [
        click.option("--topic", default=None,
                     help="Image topic of a bag [default: the calibration's rostopic, else the only image topic]."),
        click.option("--every", default=1, show_default=True, help="Keep every Nth frame of a recording."),
        click.option("--min-interval", default=0.0, show_default=True, metavar="SECONDS",
                     help="Keep frames at least this far apart (after --every)."),
        click.option("--start", default=None, type=float, metavar="SECONDS",
                     help="Skip the frames before this time, from the recording's first frame."),
        click.option("--end", default=None, type=float, metavar="SECONDS",
                     help="Stop at this time, from the recording's first frame."),
    ])


json_option = click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")


csv_option = click.option("--csv", "csv_path", default=None, type=click.Path(dir_okay=False),
                          help="Also write the numbers to this CSV file.")


plot_option = click.option("--plot", "plot_path", default=None, type=click.Path(dir_okay=False),
                           help="Also draw a figure to this PNG file (needs the 'plot' extra: matplotlib).")


@click.group(cls=AppdgenGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="appdgen")
def main() -> None:
    """Self-labelled data for learning camera miscalibration detection (APPD labels)."""


def format_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table: first column left-aligned, the others right-aligned to their widest cell."""
    cells = [list(header), *map(list, rows)]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    return "\n".join("  ".join(cell.ljust(w) if i == 0 else cell.rjust(w)
                                for i, (cell, w) in enumerate(zip(row, widths, strict=False))) for row in cells)


def write_csv(path: str, header: Sequence[str], rows: Iterable[Sequence[object]]) -> None:
    """Write a CSV file atomically: numbers at full precision, NaN as 'nan'."""
    from appdgen.util.atomic import write_file

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
        from appdgen.analysis.plots import require

        require()
