"""CLI commands for the paper's analyses: APPD against parameters, against reprojection error, across files."""
from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import click
import numpy as np

from appdgen.calib.calibration import Calibration
from appdgen.cli.base import (
    calib_option,
    camera_option,
    csv_option,
    describe_source,
    fail_cleanly,
    format_table,
    json_option,
    load_calibration,
    main,
    max_fov_option,
    note,
    plot_option,
    size_option,
    start_plot,
    write_csv,
)
from appdgen.errors import AppdgenError
from appdgen.util.sizes import parse_size


@main.command()
@calib_option
@camera_option
@click.option("--params", default=None,
              help="Comma-separated parameters, each swept alone  [default: fx, fy, cx, cy and every coefficient "
                   "of the calibration's lens model]")
@click.option("--from", "start", type=float, default=-0.2, show_default=True,
              help="First fraction t: value x (1 + t).")
@click.option("--to", "stop", type=float, default=0.2, show_default=True, help="Last fraction t.")
@click.option("--steps", type=int, default=101, show_default=True,
              help="Number of t values, evenly spaced, ends included.")
@size_option
@max_fov_option
@csv_option
@plot_option
@fail_cleanly
def sweep(calib_path, camera, params, start, stop, steps, size, max_fov, csv_path, plot_path):
    """APPD as each parameter alone is multiplied by (1 + t), the others fixed (the paper's per-parameter figure).

    APPD, in % of the raw diagonal, is against the unperturbed calibration. Parameters equal to 0 are skipped
    (multiplying 0 changes nothing); t values giving an invalid calibration (distortion folding over, focal
    length <= 0) give NaN and are counted on stderr. Prints t against APPD at five t values; --csv has them all.
    The default output size is the raw size, for fidelity; a quarter of it per side (--size 348x128 for KITTI)
    runs about 3 times faster and moves KITTI's APPD by under 0.0001 % of the diagonal.
    """
    from appdgen.analysis.studies import sweep as sweep_appd
    from appdgen.analysis.studies import sweep_fractions

    start_plot(plot_path)
    calib = load_calibration(calib_path, camera)
    names = list(calib.param_names if params is None
                 else dict.fromkeys(n.strip() for n in params.split(",") if n.strip()))
    t = sweep_fractions(start, stop, steps)
    out_size = parse_size(size)
    curves = sweep_appd(calib, names, t, out_size, max_fov)
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
        from appdgen.analysis.plots import plot_sweep

        plot_sweep(Path(plot_path), t, curves, f"APPD as one parameter changes, others fixed: "
                   f"{describe_source(calib_path, camera)} (output {w}x{h})", calib.diagonal, calib.param_names)


@main.command()
@calib_option
@camera_option
@click.option("--samples", type=int, default=500, show_default=True, help="Valid calibrations Θm to sample.")
@click.option("--scenario", type=click.Choice(["synthetic", "physical", "both"]), default="both", show_default=True,
              help="Which reprojection error: (a) synthetic, (b) physical, or both on the same Θm.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (points, then calibrations).")
@click.option("--points", type=int, default=1000, show_default=True, help="3-D points per calibration.")
@size_option
@max_fov_option
@csv_option
@plot_option
@fail_cleanly
def reproj(calib_path, camera, samples, scenario, seed, points, size, max_fov, csv_path, plot_path):
    """APPD against reprojection error for calibrations Θm sampled around the file's Θ* (the paper's scatter figure).

    Θm = Θ* x (1 + t), with t uniform per parameter in the paper's ranges: fx, fy -5..+20 %, cx, cy +-5 %,
    every coefficient of the lens model (k1, k2, p1, p2, k3 for radtan) +-15 %; draws whose distortion folds
    over are skipped and counted. The 3-D points are
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
    from appdgen.analysis.studies import SCENARIOS, reprojection_study, spearman

    start_plot(plot_path)
    calib = load_calibration(calib_path, camera)
    scenarios = SCENARIOS if scenario == "both" else (scenario,)
    study = reprojection_study(calib, samples, scenarios, seed, parse_size(size), points, max_fov=max_fov)
    source = describe_source(calib_path, camera)
    click.echo(f"{source}: {samples} calibrations sampled in the paper's ranges ({study.skipped} invalid draws "
               f"skipped), {points} points, seed {seed}, output {study.size[0]}x{study.size[1]}")
    click.echo(f"APPD: {np.min(study.appd_pct):.3f} .. {np.max(study.appd_pct):.3f} % of the diagonal "
               f"(median {np.median(study.appd_pct):.3f} %)")
    for name, error in study.reproj_px.items():
        click.echo(f"{name}: reprojection error {np.nanmin(error):.2f} .. {np.nanmax(error):.2f} px (median "
                   f"{np.nanmedian(error):.2f} px); Spearman rho(APPD, error) = {spearman(study.appd_pct, error):.3f}")
    if csv_path:
        header = ["sample", *(f"t_{p}" for p in study.params), "appd_px", "appd_pct",
                  *(f"reproj_{n}_px" for n in scenarios)]
        write_csv(csv_path, header, ([i, *study.fractions[i].tolist(), study.appd_px[i], study.appd_pct[i],
                                      *(study.reproj_px[n][i] for n in scenarios)] for i in range(samples)))
    if plot_path:
        from appdgen.analysis.plots import plot_reproj

        plot_reproj(Path(plot_path), study,
                    f"APPD against reprojection error: {samples} calibrations sampled around {source}")


def file_labels(paths: Sequence[str]) -> list[str]:
    """File names; the parent folder's name for files sharing a base name (KITTI <day>/calib_cam_to_cam.txt)."""
    names = [Path(p).name for p in paths]
    labels = [Path(p).resolve().parent.name if names.count(n) > 1 else n for p, n in zip(paths, names, strict=True)]
    return labels if len(set(labels)) == len(labels) else list(paths)


def common_cameras(paths: Sequence[str]) -> list[str]:
    """The camera names every file has, in the first file's order."""
    from appdgen.calib.formats import list_cameras

    listed = [list_cameras(Path(p)) for p in paths]
    common = [name for name in listed[0] if all(name in other for other in listed[1:])]
    if not common:
        raise AppdgenError("the files have no camera name in common; choose one with --camera")
    return common


def rounding_note(labels: Sequence[str], calibs: Sequence[Calibration], size: tuple[int, int] | None,
                  max_fov: float | None = None) -> str | None:
    """A note naming calibrations with at most 3 significant digits, with the APPD that such rounding alone gives."""
    from appdgen.analysis.studies import round_significant
    from appdgen.geometry.appd import appd_px
    from appdgen.geometry.maps import rectify as rectify_calibration

    rounded = [label for label, c in zip(labels, calibs, strict=True) if round_significant(c, 3) == c]
    full = [(label, c) for label, c in zip(labels, calibs, strict=True) if label not in rounded]
    if not rounded:
        return None
    text = f"{', '.join(rounded)}: values have at most 3 significant digits, so part of their APPD is rounding"
    if full:
        label, c = full[0]
        floor = appd_px(rectify_calibration(c, size, max_fov=max_fov),
                        rectify_calibration(round_significant(c, 3), size, max_fov=max_fov))
        text += f" (rounding {label} to 3 digits alone gives {floor:.2f} px)"
    return text


@main.command()
@click.argument("calib_paths", nargs=-1, required=True, type=click.Path(dir_okay=False), metavar="CALIB...")
@click.option("--camera", "cameras", multiple=True,
              help="Camera to compare, e.g. 02 (repeatable; default: every camera that all files have).")
@size_option
@max_fov_option
@json_option
@plot_option
@fail_cleanly
def drift(calib_paths, cameras, size, max_fov, as_json, plot_path):
    """APPD between the same camera's calibrations in several files, e.g. KITTI's recording days.

    The files may use different formats and lens models (e.g. a fisheye as kb4 in one file, ds in another).

    For each camera, prints the symmetric matrix of APPD between every pair of files, in raw px and in % of
    the raw diagonal. Files are labelled by their name, or by their folder's name where files share a name
    (KITTI's <day>/calib_cam_to_cam.txt). Files whose values all have at most 3 significant digits (the reduced
    KITTI days) are noted on stderr with the APPD that such rounding alone causes.
    """
    start_plot(plot_path)
    labels = file_labels(calib_paths)
    out_size = parse_size(size)
    tables = {camera: drift_table(calib_paths, labels, camera, out_size, max_fov)
              for camera in cameras or common_cameras(calib_paths)}
    if as_json:
        click.echo(json.dumps({"files": list(calib_paths), "labels": labels, "cameras": {
            camera: {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in table.items()}
            for camera, table in tables.items()}}, indent=2))
    else:
        for camera, table in tables.items():
            echo_drift(camera, table, labels)
    if plot_path:
        from appdgen.analysis.plots import plot_drift

        w, h = next(iter(tables.values()))["size"]
        plot_drift(Path(plot_path), {cam: (labels, t["appd_px"], t["diagonal_px"]) for cam, t in tables.items()},
                   f"APPD between calibrations of the same camera (output {w}x{h}; cells: raw px and % of diagonal)")


def drift_table(paths: Sequence[str], labels: Sequence[str], camera: str, size: tuple[int, int] | None,
                max_fov: float | None = None) -> dict:
    """One camera's APPD matrix between the files (raw px and %), its output size and diagonal, a rounding note."""
    from appdgen.analysis.studies import drift_matrix

    calibs = [load_calibration(p, camera) for p in paths]
    matrix = drift_matrix(calibs, size, labels, max_fov)
    diagonal = calibs[0].diagonal
    return {"size": list(size or calibs[0].size), "diagonal_px": diagonal, "appd_px": matrix,
            "appd_pct": matrix * 100 / diagonal, "note": rounding_note(labels, calibs, size, max_fov)}


def echo_drift(camera: str, table: dict, labels: Sequence[str]) -> None:
    """Print one camera's drift matrices, in raw px then in % of the diagonal, and its rounding note (stderr)."""
    w, h = table["size"]
    for key, unit in (("appd_px", "raw px"), ("appd_pct", f"% of the {table['diagonal_px']:.1f} px diagonal")):
        click.echo(f"camera {camera}: APPD in {unit} (output {w}x{h})")
        rows = [[label, *(f"{v:.3f}" for v in row)] for label, row in zip(labels, table[key], strict=True)]
        click.echo(format_table(["", *labels], rows) + "\n")
    if table["note"]:
        note(f"camera {camera}: {table['note']}")
