"""CLI commands on one calibration: APPD between calibrations, rectifying one image."""
from __future__ import annotations

import json
from pathlib import Path

import click

from appdgen.calib.calibration import Calibration
from appdgen.cli.base import (
    calib_option,
    camera_option,
    fail_cleanly,
    interp_option,
    json_option,
    load_calibration,
    main,
    max_fov_option,
    modified,
    perturb_option,
    set_option,
    size_option,
)
from appdgen.errors import AppdgenError
from appdgen.util.sizes import parse_size


def _describe(calib: Calibration, new_k) -> dict:
    """A calibration's lens model, its parameters, size and output camera matrix K̂, JSON-ready."""
    return {"model": calib.model, **calib.params(), "size": list(calib.size), "new_camera_matrix": new_k.tolist()}


@main.command()
@calib_option
@camera_option
@set_option
@perturb_option
@click.option("--against", "against_path", default=None, type=click.Path(dir_okay=False),
              help="Compare with this second calibration file instead of a perturbation.")
@click.option("--against-camera", default=None, help="Camera in the --against file (default: --camera).")
@size_option
@max_fov_option
@json_option
@fail_cleanly
def appd(calib_path, camera, sets, perturbs, against_path, against_camera, size, max_fov, as_json):
    """APPD between a reference calibration and a perturbed (or second) one.

    The two may use different lens models (e.g. one fisheye calibrated as kb4 and as ds): APPD compares the
    rectification maps, whatever model made them. --set and --perturb apply to the second calibration and take
    its model's parameter names.
    """
    from appdgen.geometry.appd import appd_px, px_to_pct
    from appdgen.geometry.maps import rectify

    reference = load_calibration(calib_path, camera)
    other = load_calibration(against_path, against_camera or camera) if against_path else reference
    other = modified(other, sets, perturbs)
    if other.size != reference.size:
        raise AppdgenError(f"{against_path}: raw size {other.width}x{other.height} differs from {calib_path}'s "
                           f"{reference.width}x{reference.height}; APPD compares one camera's calibrations")
    out_size = parse_size(size)
    ref_rect, other_rect = rectify(reference, out_size, max_fov=max_fov), rectify(other, out_size, max_fov=max_fov)
    value = appd_px(ref_rect, other_rect)
    result = {
        "appd_px": value,
        "appd_pct": px_to_pct(value, reference),
        "size": list(ref_rect.size),
        "reference": _describe(reference, ref_rect.new_camera_matrix),
        "perturbed": _describe(other, other_rect.new_camera_matrix),
    }
    if max_fov is not None:
        result["max_fov"] = max_fov
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
@max_fov_option
@interp_option
@click.argument("image", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Output image (PNG, JPG…).")
@fail_cleanly
def rectify(calib_path, camera, sets, perturbs, size, max_fov, interp, image, output):
    """Rectify, crop and rescale one raw image with a (perturbed) calibration."""
    from appdgen.dataset.images import write_image
    from appdgen.geometry.maps import rectify as rectify_calibration
    from appdgen.geometry.remap import remap_image
    from appdgen.sources.decode import read_image

    calib = modified(load_calibration(calib_path, camera), sets, perturbs)
    rect = rectify_calibration(calib, parse_size(size), max_fov=max_fov)
    write_image(Path(output), remap_image(read_image(Path(image)), rect, interp))
    click.echo(f"wrote {output} ({rect.size[0]}x{rect.size[1]})")
