"""`evaluate`: error metrics of a checkpoint on one split, per APPD bin, plus a predicted-vs-true plot."""
from __future__ import annotations

import json
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import torch

from appdgen.analysis.plots import plot_predictions
from appdgen.dataset.layout import TARGETS
from appdgen.dataset.shardset import open_shards, read_labels, target_labels
from train import checkpoint, runtime
from train.data import Selection, StreamSpec, make_loader
from train.errors import TrainError
from train.inference import predict
from train.scoring import SEQUENCE_SEED, bin_edges, bin_index, metrics, sequence_metrics, sequence_pairs
from train.scoring import THRESHOLD as DETECTION_THRESHOLD


def predict_split(model: torch.nn.Module, loader: Iterable[dict], device: torch.device, dtype: torch.dtype | None
                  ) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(keys, true labels, predictions; the target's %) over every sample a loader yields."""
    keys: list[str] = []
    true: list[np.ndarray] = []
    pred: list[np.ndarray] = []
    for batch, out in predict(model, loader, device, dtype):
        keys += list(batch["key"])
        true.append(batch["label"].numpy())
        pred.append(out.cpu().numpy())
    if not keys:
        raise TrainError("no samples to evaluate")
    return keys, np.concatenate(true).astype(float), np.concatenate(pred).astype(float)


def write_json(path: str, result: dict) -> None:
    """An evaluation's metrics as a JSON file (its folder made when missing)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(result, indent=1))


def evaluate(ckpt_path: str, shards: str, split: str, json_path: str | None = None, plot_path: str | None = None,
             threshold: float = DETECTION_THRESHOLD, batch: int = 64, workers: int = 1, device: str = "auto",
             precision: str = "fp32") -> dict:
    """Run the checkpoint over one split of the shards; returns (and optionally writes) the metrics."""
    dev = runtime.pick_device(device)
    runtime.setup_threads(dev)
    ckpt = checkpoint.load(ckpt_path)
    model = checkpoint.build_model(ckpt).to(dev).to(memory_format=torch.channels_last)
    ss = open_shards(shards)
    if ss.build and ss.split_count(split) == 0:
        raise TrainError(f"{ss.root}: no samples of split {split!r}")
    mismatch = checkpoint.rule_mismatch(ckpt, ss.rectify_rule())
    if mismatch:  # a legitimate cross-rule experiment, but not the detector's training distribution
        print(f"evaluate: note: {mismatch}", file=sys.stderr)
    cfg, target = model.cfg, checkpoint.target(ckpt)
    # appd: the json members' label; another target's only labels.parquet holds.
    labels = None if target == "appd" else target_labels(read_labels(ss.root, target), target)
    spec = StreamSpec(ss.for_split(split), Selection(split), (cfg.width, cfg.height), labels=labels)
    _, y_true, y_pred = predict_split(model, make_loader(spec, batch, workers), dev,
                                      runtime.autocast_dtype(dev, precision))
    appd_max = ss.appd_max or ckpt["config"].get("appd_max") or float(max(y_true.max(), 1e-6))
    result = {"checkpoint": str(ckpt_path), "shards": str(ss.root), "split": split, "target": target,
              "label": TARGETS[target],
              **metrics(y_true, y_pred, checkpoint.label_mean(ckpt), appd_max, threshold)}
    if json_path:
        write_json(json_path, result)
    if plot_path:
        edges = bin_edges(appd_max)
        plot_predictions(Path(plot_path), edges, bin_index(y_true, edges), y_pred, threshold,
                         f"{split}: MAE {result['mae']:.3f}% (mean predictor {result['mean_predictor_mae']:.3f}%)",
                         "APPD" if target == "appd" else target)
        result["plot"] = str(plot_path)
    return result


def frames_recipe(ckpt: dict, ckpt_path: str, frames: str):
    """(the fit --online run's PairRecipe, the listed raw frames) with `frames` for its images: the same
    calibration, output size, sampling and target as the fit drew its pairs with."""
    from train.online.options import OnlineOptions
    from train.online.recipe import open_recipe

    online = ckpt["config"].get("fit", {}).get("online")
    if not online:
        raise TrainError(f"{ckpt_path}: --frames needs a checkpoint of fit --online (it renders the test pairs with "
                         "that fit's calibration and sampling); evaluate a --shards fit with --shards")
    return open_recipe(OnlineOptions(**{**online, "images": frames, "split_by": "none", "val_shards": None}),
                       checkpoint.target(ckpt))


def evaluate_frames(ckpt_path: str, frames: str, length: int = 10, sequences: int | None = None,
                    draw_seed: int | None = None, json_path: str | None = None, threshold: float = DETECTION_THRESHOLD,
                    batch: int = 32, device: str = "auto", precision: str = "fp32") -> dict:
    """Score a fit --online checkpoint on raw frames it has not seen, per frame and per sequence: sequence k is
    frames k·length … k·length + length − 1 (in file order) under one miscalibration, the fixed-seed draw
    (draw_seed, k) of the fit's own calibration and sampling (train.scoring.sequence_pairs, as the detector
    comparison's axes); the sequence's mean and median prediction are scored against its label (ratios to the mean
    predictor's MAE)."""
    from train.online.recipe import decode_frames

    if length < 1:
        raise TrainError(f"--length {length}: must be at least 1")
    dev = runtime.pick_device(device)
    runtime.setup_threads(dev)
    ckpt = checkpoint.load(ckpt_path)
    target = checkpoint.target(ckpt)
    recipe, images = frames_recipe(ckpt, ckpt_path, frames)
    raw = decode_frames(images)
    if len(raw) < length:
        raise TrainError(f"{frames}: {len(raw)} frames, fewer than one sequence of --length {length}")
    seed = SEQUENCE_SEED if draw_seed is None else draw_seed
    pairs = sequence_pairs(recipe, raw, seed, sequences or len(raw), length)
    model = checkpoint.build_model(ckpt).to(dev).to(memory_format=torch.channels_last)
    n = len(pairs[target])
    cut = [slice(i, min(i + batch, n)) for i in range(0, n, batch)]
    batches = ({"image": torch.from_numpy(pairs["image"][c]), "label": torch.from_numpy(pairs[target][c]),
                "key": list(map(str, range(c.start, c.stop)))} for c in cut)
    _, y_true, y_pred = predict_split(model, batches, dev, runtime.autocast_dtype(dev, precision))
    mean = checkpoint.label_mean(ckpt)
    appd_max = ckpt["config"].get("appd_max") or float(max(y_true.max(), 1e-6))
    per_sequence = sequence_metrics(y_pred, y_true, pairs["appd"], mean, length)
    result = {"checkpoint": str(ckpt_path), "frames": str(frames), "split": Path(frames).name, "target": target,
              "label": TARGETS[target], **metrics(y_true, y_pred, mean, appd_max, threshold),
              "sequences": {"length": length, "draw_seed": seed, "count": per_sequence["sequences"],
                            "mean_vs_mean_predictor": per_sequence["seq_mean"],
                            "median_vs_mean_predictor": per_sequence["seq_median"],
                            "ratio_se": per_sequence["ratio_se"], "spearman": per_sequence["rho"],
                            # how well the per-frame prediction ranks "APPD above the detector table's threshold"
                            "detection_auc": per_sequence["auc"], "detection_threshold": DETECTION_THRESHOLD}}
    if json_path:
        write_json(json_path, result)
    return result
