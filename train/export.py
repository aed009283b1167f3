"""`export`: torch.export (.pt2) and ONNX files of a checkpoint, each checked against eager PyTorch.

No TorchScript: torch 2.13 deprecates torch.jit (trace and script) in favour of torch.export, whose
ExportedProgram is what ONNX export already goes through here, loads with torch.export.load, and compiles
ahead of time for C++ (AOTInductor). One graph-capture path keeps both files from drifting apart.
"""
from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path

import numpy as np
import torch

from train import checkpoint
from train.errors import TrainError
from train.model import AppdNet
from train.nets import image_features

#: Largest |exported − eager| accepted, in APPD % (the model's output unit).
TOLERANCE = 1e-4


def metadata(model: AppdNet, ckpt: dict) -> dict:
    """What a deployment needs to feed the exported model: input layout, range, order, output unit."""
    cfg = model.cfg
    return {
        "input": f"float32 N x {cfg.in_channels} x {cfg.height} x {cfg.width}, values in [0, 1], channel order "
                 f"{cfg.channels}",
        "output": f"float32 N: predicted {checkpoint.label_column(ckpt)}, % of the raw image diagonal",
        "target": checkpoint.target(ckpt),
        "normalization": "included in the model", "width": cfg.width, "height": cfg.height,
        "channels": cfg.channels, "label_mean": checkpoint.label_mean(ckpt), "step": int(ckpt["step"]),
        "rectify": checkpoint.rectify_rule(ckpt),  # rectify raw images as the training build did (max_fov, interp)
    }


def example(model: AppdNet, n: int = 2, seed: int = 0) -> torch.Tensor:
    """A reproducible random input batch at the network size."""
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, model.cfg.in_channels, model.cfg.height, model.cfg.width, generator=g)


def to_pt2(model: AppdNet, path: Path, meta: dict) -> float:
    """Save torch.export's program (dynamic batch; config in extra file config.json); returns max |diff| vs eager
    of the reloaded program on a batch of another size."""
    batch = torch.export.Dim("batch", min=1)
    program = torch.export.export(model.eval(), (example(model),), dynamic_shapes=({0: batch},))
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.export.save(program, str(path), extra_files={"config.json": json.dumps(meta)})
    loaded = torch.export.load(str(path)).module()
    x = example(model, n=3, seed=1)
    with torch.no_grad():
        return float((loaded(x) - model(x)).abs().max())


def to_onnx(model: AppdNet, path: Path, meta: dict) -> float | None:
    """Export ONNX (dynamic batch, one file); returns max |diff| vs eager, None if no runtime to check."""
    try:
        import onnx
        import onnxscript  # noqa: F401 - torch's exporter needs it; fail early with our message
    except ImportError as exc:
        raise TrainError(f"ONNX export needs the onnx and onnxscript packages ({exc}); "
                         "pip install -e .[train] or omit --onnx") from None
    path.parent.mkdir(parents=True, exist_ok=True)
    batch = torch.export.Dim("batch", min=1)
    # torch's exporter logs optional-torchvision notices and upstream deprecations: noise for our users.
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        torch.onnx.export(model, (example(model),), str(path), input_names=["image"], output_names=["appd_pct"],
                          dynamic_shapes={"x": {0: batch}}, external_data=False, verbose=False)
    proto = onnx.load(str(path))
    onnx.helper.set_model_props(proto, {k: v if isinstance(v, str) else json.dumps(v) for k, v in meta.items()})
    onnx.save(proto, str(path))
    x = example(model, n=3, seed=1)
    got = run_onnx(path, x.numpy())
    if got is None:
        return None
    with torch.no_grad():
        return float(np.abs(got - model(x).numpy()).max())


def run_onnx(path: Path, x: np.ndarray) -> np.ndarray | None:
    """Run an ONNX file with onnxruntime, else onnx's reference evaluator; None if neither exists."""
    try:
        import onnxruntime as ort

        return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"image": x})[0]
    except ImportError:
        pass
    try:
        from onnx.reference import ReferenceEvaluator
    except ImportError:
        return None
    return ReferenceEvaluator(str(path)).run(None, {"image": x})[0]


def check(name: str, diff: float | None) -> None:
    """Print the parity result; raise when it exceeds the tolerance."""
    if diff is None:
        print(f"export: {name}: written; parity not checked (no onnxruntime or onnx reference evaluator)")
        return
    verdict = "ok" if diff <= TOLERANCE else "FAILED"
    print(f"export: {name}: max |exported - eager| = {diff:.2e} APPD % (tolerance {TOLERANCE:g}) {verdict}")
    if diff > TOLERANCE:
        raise TrainError(f"{name}: exported model disagrees with eager PyTorch by {diff:.2e}")


def to_json(model: torch.nn.Module, path: Path, meta: dict) -> float:
    """The plumb-line floor as train.plumbline's JSON (with meta), which PlumbLine.load reads without torch;
    returns the largest difference between the reloaded detector and the module on example images."""
    from train.plumbline import PlumbLine

    floor = model.floor()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**floor.to_dict(), "meta": meta}, indent=1), encoding="utf-8")
    x = example(model)
    reloaded = PlumbLine.load(path).predict_features(image_features(x))
    with torch.no_grad():
        return float(np.abs(reloaded - model(x).double().numpy()).max())


def export(ckpt_path: str, onnx_path: str | None = None, pt2_path: str | None = None,
           json_path: str | None = None) -> dict:
    """Write the requested files, printing a parity line for each; returns {format: max diff}."""
    if not onnx_path and not pt2_path and not json_path:
        raise TrainError("nothing to export: give --onnx and/or --pt2 (a network), or --json (the plumb-line floor)")
    ckpt = checkpoint.load(ckpt_path)
    model = checkpoint.build_model(ckpt)
    meta = metadata(model, ckpt)
    floor = model.cfg.arch == "plumbline"
    if floor and (onnx_path or pt2_path):
        raise TrainError(f"{ckpt_path}: the plumb-line floor runs OpenCV's line detector, which neither ONNX nor "
                         "torch.export can hold; export it with --json (train.plumbline.PlumbLine.load reads "
                         "it without torch)")
    if json_path and not floor:
        raise TrainError(f"{ckpt_path}: --json writes the plumb-line floor; this checkpoint is the "
                         f"{model.cfg.arch} network: export it with --onnx or --pt2")
    result: dict[str, float | None] = {}
    if json_path:
        result["json"] = to_json(model, Path(json_path), meta)
        check(str(json_path), result["json"])
    if pt2_path:
        result["pt2"] = to_pt2(model, Path(pt2_path), meta)
        check(str(pt2_path), result["pt2"])
    if onnx_path:
        result["onnx"] = to_onnx(model, Path(onnx_path), meta)
        check(str(onnx_path), result["onnx"])
    return result
