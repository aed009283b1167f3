"""Figures for the analyses (optional extra ``plot``: matplotlib is imported only when a figure is drawn)."""
from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from appdgen.analysis.studies import ReprojectionStudy, spearman
from appdgen.calib.calibration import FOCAL, PRINCIPAL
from appdgen.errors import AppdgenError
from appdgen.util.atomic import write_file

_SCENARIO_TITLES = {
    "synthetic": "(a) synthetic: the reference camera's image\nrectified with the sampled calibration",
    "physical": "(b) physical: the camera drifted to the sampled calibration,\n"
                "its image rectified with the reference one",
}


def require() -> None:
    """Raise AppdgenError unless matplotlib (the optional ``plot`` extra) is importable."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise AppdgenError("--plot needs matplotlib: pip install 'appdgen[plot]'") from None


def _figure(width: float, height: float) -> Any:
    """A matplotlib Figure not tied to any GUI backend (no pyplot state)."""
    require()
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def _save(fig: Any, path: Path) -> None:
    """Render to PNG (or the format the extension names) and write atomically."""
    kind = path.suffix.lstrip(".").lower() or "png"
    buffer = io.BytesIO()
    try:
        fig.savefig(buffer, format=kind, dpi=100)
    except ValueError as exc:  # an extension matplotlib cannot write
        raise AppdgenError(f"{path}: {exc}") from None
    write_file(path, _palette_png(buffer.getvalue()) if kind == "png" else buffer.getvalue())


def _palette_png(data: bytes) -> bytes:
    """The PNG with a 256-colour palette: about a third of the bytes, no visible change for these plots."""
    from PIL import Image  # a dependency of matplotlib

    output = io.BytesIO()
    Image.open(io.BytesIO(data)).convert("RGB").quantize(256).save(output, format="PNG", optimize=True)
    return output.getvalue()


def _style(name: str) -> str:
    """Line style of a parameter's curve: solid focal length, dashed principal point, dotted lens coefficient."""
    return "-" if name in FOCAL else "--" if name in PRINCIPAL else ":"


def plot_sweep(path: Path, fractions: np.ndarray, curves: Mapping[str, np.ndarray], title: str,
               diagonal: float, params: Sequence[str]) -> None:
    """APPD (% of the diagonal, and raw px) against t (%), one line per parameter; linear and log panels.

    `params` is the calibration's parameter list (``calib.param_names``): a parameter's colour is its place there.
    """
    fig = _figure(11, 5.0)
    linear, log = fig.subplots(1, 2)
    colours = {name: f"C{i % 10}" for i, name in enumerate(params)}  # matplotlib's cycle has ten colours
    for name, values in curves.items():
        for ax in (linear, log):
            ax.plot(100 * fractions, values, _style(name), color=colours[name], label=name, lw=1.8)
    log.set_yscale("log", nonpositive="mask")  # p1, p2, k3 sit orders of magnitude below cx: only log shows them
    for ax, kind in ((linear, "linear"), (log, "log")):
        ax.set_xlabel("parameter change t (%): value × (1 + t)")
        ax.set_ylabel("APPD (% of image diagonal)")
        ax.set_title(f"{kind} scale")
        ax.grid(True, which="major", alpha=0.3)
        ax.axvline(0, color="0.5", lw=0.8)
    pixels = linear.secondary_yaxis("right", functions=(lambda p: p * diagonal / 100, lambda x: x * 100 / diagonal))
    pixels.set_ylabel("APPD (raw px)")
    fig.legend(*linear.get_legend_handles_labels(), loc="outside lower center", ncol=min(len(curves), 9),
               title="parameter changed (solid: focal length, dashed: principal point, dotted: distortion)")
    fig.suptitle(title)
    _save(fig, path)


def plot_reproj(path: Path, study: ReprojectionStudy, title: str) -> None:
    """Reprojection error (output px) against APPD (% of the diagonal), a panel per scenario, coloured by fx's t."""
    names = list(study.reproj_px)
    fig = _figure(5.2 * len(names) + 0.8, 4.4)
    axes = np.atleast_1d(fig.subplots(1, len(names), squeeze=False)[0])
    focal = 100 * study.fractions[:, study.params.index("fx")]
    for ax, name in zip(axes, names, strict=False):
        error = study.reproj_px[name]
        dots = ax.scatter(study.appd_pct, error, c=focal, s=9, cmap="viridis", alpha=0.8)
        ax.set_title(f"{_SCENARIO_TITLES[name]}\nSpearman ρ = {spearman(study.appd_pct, error):.3f}, "
                     f"n = {np.isfinite(error).sum()}", fontsize="medium")
        ax.set_xlabel("APPD (% of image diagonal)")
        ax.set_ylabel(f"mean reprojection error (px of the {study.size[0]}x{study.size[1]} output)")
        ax.grid(True, alpha=0.3)
    fig.colorbar(dots, ax=list(axes), label="fx change (%)")
    fig.suptitle(title)
    _save(fig, path)


def plot_drift(path: Path, tables: Mapping[str, tuple[Sequence[str], np.ndarray, float]], title: str) -> None:
    """A heat map per camera of APPD between calibrations: (labels, matrix in raw px, raw diagonal in px)."""
    fig = _figure(5.0 * len(tables) + 0.8, 4.6)
    axes = fig.subplots(1, len(tables), squeeze=False)[0]
    top = max(float(m.max()) for _, m, _ in tables.values()) or 1.0
    for ax, (camera, (labels, matrix, diagonal)) in zip(axes, tables.items(), strict=False):
        image = ax.imshow(matrix, cmap="magma_r", vmin=0.0, vmax=top)
        for (i, j), value in np.ndenumerate(matrix):
            ax.text(j, i, f"{value:.2f} px\n{value * 100 / diagonal:.3f} %", ha="center", va="center",
                    fontsize="x-small", color="white" if value > 0.6 * top else "black")
        ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
        ax.set_yticks(range(len(labels)), labels)
        ax.set_title(f"camera {camera}")
        ax.set_xlabel("calibration")
        ax.set_ylabel("calibration")
    fig.colorbar(image, ax=list(axes), label="APPD (raw px)")
    fig.suptitle(title)
    _save(fig, path)


def plot_predictions(path: Path, edges: np.ndarray, bins: np.ndarray, y_pred: np.ndarray, threshold: float,
                     title: str, quantity: str = "APPD") -> None:
    """Box plots of a detector's predictions (% of the diagonal) per bin of the true label (`bins`: each
    prediction's bin among `edges`; `quantity`: APPD, or the target learnt) against the identity line."""
    fig = _figure(7, 5)
    ax = fig.subplots()
    groups = [(0.5 * (edges[b] + edges[b + 1]), y_pred[bins == b]) for b in range(len(edges) - 1)]
    groups = [(c, g) for c, g in groups if len(g)]
    ax.boxplot([g for _, g in groups], positions=[c for c, _ in groups], widths=0.7 * (edges[1] - edges[0]),
               manage_ticks=False, showfliers=True, flierprops={"markersize": 2})
    ax.plot([0, edges[-1]], [0, edges[-1]], "--", color="tab:green", label="ideal")
    ax.axhline(threshold, color="tab:red", lw=0.8, label=f"threshold {threshold:g}%")
    ax.set(xlabel=f"true {quantity} (% of diagonal), binned", ylabel=f"predicted {quantity} (% of diagonal)",
           title=title, xlim=(0, edges[-1]))
    ax.legend(loc="upper left")
    _save(fig, path)


def plot_detect(path: Path, windows: Sequence[Mapping], threshold_pct: float, image: np.ndarray,
                points: tuple[np.ndarray, np.ndarray, np.ndarray], grid: tuple[np.ndarray, np.ndarray, np.ndarray],
                title: str) -> None:
    """appdgen detect's figure: each window's APPD reading (% of the raw diagonal) over its frames with ±2 sd and
    the threshold; one rectified frame with its edge points coloured by their segment's weight in the solve
    (points: u, v, weight; output px) and the solved field (grid: u, v, (gy, gx, 2) px) as arrows."""
    fig = _figure(11, 7.5)
    top, bottom = fig.subplots(2, 1, height_ratios=[1, 1.6])
    for w in windows:
        span = (w["first"], w["first"] + w["count"] - 1)
        if w["appd_pct"] is None:
            top.axvspan(span[0], span[1] + 1, color="0.9")
            continue
        mean, sd = w["appd_pct"], w["appd_sd_pct"]
        colour = "tab:red" if w["verdict"] == "miscalibrated" else "tab:blue"
        top.fill_between([span[0], span[1] + 1], max(mean - 2 * sd, 0.0), mean + 2 * sd, color=colour, alpha=0.2)
        top.plot([span[0], span[1] + 1], [mean, mean], color=colour, lw=2)
    top.axhline(threshold_pct, color="k", ls="--", lw=1, label=f"threshold {threshold_pct:g} %")
    top.set_xlabel("frame")
    top.set_ylabel("APPD % (±2 sd)")
    top.set_ylim(bottom=0)
    top.legend(loc="upper right")
    top.set_title(title)
    bottom.imshow(image, cmap="gray", vmin=0, vmax=255)
    u, v, weight = points
    shown = bottom.scatter(u, v, c=weight / max(float(weight.max()), 1e-300) if weight.size else weight, s=1.5,
                           cmap="viridis", vmin=0, vmax=1)
    gu, gv, field = grid
    uu, vv = np.meshgrid(gu, gv)
    bottom.quiver(uu, vv, field[..., 0], field[..., 1], color="tab:orange", angles="xy", scale_units="xy",
                  scale=0.1, width=0.002)
    bottom.set_title("frame 0: edge points by their segment's weight; the solved field ×10 (arrows)")
    bottom.set_axis_off()
    fig.colorbar(shown, ax=bottom, shrink=0.6, label="segment weight (of the largest)")
    _save(fig, path)
