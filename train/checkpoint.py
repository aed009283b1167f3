"""Checkpoints: plain tensors, dicts, lists, str and numbers only, so weights_only=True loads them."""
from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from appdgen.dataset.layout import TARGETS
from appdgen.util.atomic import atomic_stream
from train.errors import TrainError
from train.model import NORMALIZE, ModelConfig
from train.nets import build

FORMAT = "appdgen-train/1"


PLAIN = (str, int, float, bool, type(None), torch.Tensor)


def check_normalize(normalize: str) -> None:
    """Refuse a --normalize that is not one of NORMALIZE."""
    if normalize not in NORMALIZE:
        raise TrainError(f"--normalize must be one of {', '.join(NORMALIZE)}, got {normalize!r}")


def check_target(target: str) -> str:
    """The label column of a --target (layout.TARGETS), refusing another name."""
    if target not in TARGETS:
        raise TrainError(f"--target must be one of {', '.join(TARGETS)}, got {target!r}")
    return TARGETS[target]


def fresh(opts, size: tuple[int, int], stats: tuple[list[float], list[float], np.ndarray], channels: str,
          config: dict) -> dict:
    """A new fit's checkpoint (initial): input normalisation from the run's own images (per-channel mean and std in
    [0, 1], and the mean image C×H×W), and `config` (label mean, appd_max, crop rule, data) completed with the
    target and its label column, fit's options and torch's version."""
    mean, std, mean_image = stats
    cfg = ModelConfig(size[0], size[1], mean=tuple(mean), std=tuple(std), channels=channels, normalize=opts.normalize,
                      arch=opts.model)
    return initial(cfg, opts.seed, {"target": opts.target, "label": check_target(opts.target), **config,
                                    "fit": asdict(opts), "versions": {"torch": str(torch.__version__)}},
                   mean_image)  # TorchVersion is not weights_only-safe


def initial(cfg: ModelConfig, seed: int, config: dict, mean_image: np.ndarray | None = None) -> dict:
    """A new run's checkpoint, for fit and for every other fit of the trainer's loop (the studies' arms): the
    untrained network of `cfg` (weights seeded by `seed`; `mean_image` C×H×W for normalize 'pixel'), step 0, and
    `config` after the model's."""
    torch.manual_seed(seed)
    model = build(cfg)
    if cfg.normalize == "pixel":
        with torch.no_grad():
            model.normalize.mean.copy_(torch.from_numpy(mean_image)[None])
    return {"step": 0, "model": model.state_dict(), "optimizer": None, "config": {"model": cfg.to_dict(), **config},
            "best_val_mae": None}


def check_plain(obj: object, where: str = "checkpoint") -> None:
    """Raise if obj holds anything torch.load(weights_only=True) would refuse (caught at save, not load)."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            check_plain(k, f"{where} key")
            check_plain(v, f"{where}[{k!r}]")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            check_plain(v, f"{where}[{i}]")
    elif type(obj) not in PLAIN and not isinstance(obj, torch.Tensor):
        raise TypeError(f"{where}: {type(obj).__qualname__} is not weights_only-safe")


def save(path: Path, payload: dict) -> None:
    """Write atomically: a crash mid-save leaves the previous checkpoint intact."""
    check_plain(payload)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_stream(path) as stream:
        torch.save({"format": FORMAT, **payload}, stream)


def load(path: str | Path) -> dict:
    """Load a checkpoint onto the CPU with weights_only=True (no pickled code runs)."""
    path = Path(path)
    if not path.is_file():
        raise TrainError(f"{path}: no such checkpoint")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for corrupt or foreign files
        raise TrainError(f"{path}: not a loadable checkpoint ({type(exc).__name__}: {exc})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise TrainError(f"{path}: not an appdgen-train checkpoint (format {ckpt.get('format')!r})")
    return ckpt


def model_config(ckpt: dict) -> ModelConfig:
    """The network configuration stored in a checkpoint."""
    return ModelConfig.from_dict(ckpt["config"]["model"])


def build_model(ckpt: dict) -> torch.nn.Module:
    """The checkpoint's network (any of train.nets.MODELS) with its weights, in eval mode on the CPU."""
    model = build(model_config(ckpt))
    model.load_state_dict(ckpt["model"])
    return model.eval()


def target(ckpt: dict) -> str:
    """What the checkpoint's network predicts (a layout.TARGETS name; checkpoints from before --target: appd)."""
    return str(ckpt["config"].get("target", "appd"))


def label_column(ckpt: dict) -> str:
    """The label column the checkpoint's network predicts (appd_pct, or bend_pct)."""
    return TARGETS[target(ckpt)]


def label_mean(ckpt: dict) -> float:
    """Mean training label (the target's, % of the diagonal): what the trivial mean predictor outputs."""
    return float(ckpt["config"]["label_mean"])


def rectify_rule(ckpt: dict) -> dict | None:
    """How the training build rectified raw images ({"max_fov": degrees or None, "interp": name}); None if unrecorded
    (checkpoints from before fit recorded it, or shards without build.json)."""
    return ckpt["config"].get("rectify")


def describe_fov(max_fov: float | None) -> str:
    """'crops bounded at 120° (--max-fov)' or 'unbounded crops', for messages."""
    return "unbounded crops" if max_fov is None else f"crops bounded at {max_fov:g}° (--max-fov)"


def rule_mismatch(ckpt: dict, rule: dict | None) -> str | None:
    """Why shards rectified by `rule` differ from the checkpoint's training data (max_fov only), None if alike or
    unknown."""
    trained = rectify_rule(ckpt)
    if trained is None or rule is None or trained.get("max_fov") == rule.get("max_fov"):
        return None
    return (f"the checkpoint was trained on {describe_fov(trained.get('max_fov'))}, "
            f"these shards have {describe_fov(rule.get('max_fov'))}")
