"""The models `fit --model` chooses from (MODELS, build): the paper's CNN (train.model.AppdNet), a stride-4
patchify stem that reads full-resolution detail at about a third of the paper CNN's cost at a quarter of the
resolution, and the plumb-line floor (train.plumbline) as a module, so that fit, evaluate and predict treat
it as they treat a network.

At 348×128 the bent-line signal a single image carries is under a pixel (studies/visibility.py); the paper feeds
1392×512 for it, at 16× the cost. A 4×4/stride-4 convolution keeps each 4×4 patch's detail in its channels (48
inputs → `PATCH_FILTERS[0]` outputs), after which stride-2 convolutions work on a 348×128 grid.
"""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import torch
from torch import nn

from train import plumbline
from train.errors import TrainError
from train.model import INPUT_CHANNELS, NORMALIZE, AppdNet, ModelConfig, Normalize, Regressor

#: ModelConfig.arch → the model: the paper's CNN, the stride-4 patchify network (PatchNet), or the plumb-line floor
#: (PlumbLineNet: line curvature and a ridge, fitted in closed form, no gradient steps).
MODELS = ("paper", "patch", "plumbline")
#: The stem's patch side (pixels) and the filters of the stem and of each following stride-2 conv3×3 + ReLU.
PATCH = 4
PATCH_FILTERS: tuple[int, ...] = (32, 32, 64, 64, 128, 128)
PATCH_DENSE = 256


class PatchNet(Regressor):
    """Image batch N×C×H×W in [0, 1] → N predictions (or N×cfg.outputs): a 4×4/4 patchify stem, stride-2 convs, a
    flattened (position-keeping) dense head. cfg.filters and cfg.dense are the paper's and are not used."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        if cfg.normalize not in NORMALIZE or cfg.channels not in INPUT_CHANNELS:
            raise TrainError(f"bad model config: normalize {cfg.normalize!r}, channels {cfg.channels!r}")
        if min(cfg.width, cfg.height) < PATCH * 2 ** (len(PATCH_FILTERS) - 1):
            raise TrainError(f"images are {cfg.width}x{cfg.height} px; the patch network needs at least "
                             f"{PATCH * 2 ** (len(PATCH_FILTERS) - 1)} px a side")
        self.cfg = cfg
        self.normalize = Normalize(cfg.mean, cfg.std, (cfg.height, cfg.width) if cfg.normalize == "pixel" else None)
        layers: list[nn.Module] = [nn.Conv2d(cfg.in_channels, PATCH_FILTERS[0], PATCH, stride=PATCH), nn.ReLU(True)]
        for a, b in pairwise(PATCH_FILTERS):
            layers += [nn.Conv2d(a, b, 3, stride=2, padding=1), nn.ReLU(True)]
        self.features = nn.Sequential(*layers)
        with torch.no_grad():
            flat = self.features(torch.zeros(1, cfg.in_channels, cfg.height, cfg.width)).numel()
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(flat, PATCH_DENSE), nn.ReLU(True), nn.Dropout(cfg.dropout),
                                  nn.Linear(PATCH_DENSE, cfg.outputs))
        self.reset_parameters()


class PlumbLineNet(nn.Module):
    """Image batch N×C×H×W in [0, 1] → N predictions of the fit's target (% of diagonal) by the plumb-line floor:
    train.plumbline's features of each image, standardised, through its ridge. It has no parameters
    (nothing for an optimiser): fit solves the ridge (set_floor) and the solution lives in buffers, so a checkpoint
    holds it."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        if cfg.channels not in INPUT_CHANNELS:
            raise TrainError(f"bad model config: channels {cfg.channels!r}")
        if min(cfg.width, cfg.height) < plumbline.SMALLEST_SIDE:
            raise TrainError(f"images are {cfg.width}x{cfg.height} px; the plumb-line floor needs at least "
                             f"{plumbline.SMALLEST_SIDE} px a side")
        self.cfg = cfg
        for name in ("mean", "scale", "weights"):
            self.register_buffer(name, torch.zeros(plumbline.FEATURES, dtype=torch.float64))
        self.register_buffer("intercept", torch.zeros((), dtype=torch.float64))
        self.register_buffer("alpha", torch.zeros((), dtype=torch.float64))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))

    def set_floor(self, floor: plumbline.PlumbLine) -> None:
        """Hold a fitted ridge."""
        for name in ("mean", "scale", "weights"):
            getattr(self, name).copy_(torch.from_numpy(np.asarray(getattr(floor, name), np.float64)))
        self.intercept.fill_(floor.intercept)
        self.alpha.fill_(floor.alpha)
        self.fitted.fill_(True)

    def floor(self) -> plumbline.PlumbLine:
        """The ridge it holds, as train.plumbline's detector (AppdgenError before fit)."""
        if not bool(self.fitted):
            raise TrainError("the plumb-line floor is not fitted yet")
        return plumbline.PlumbLine(self.mean.cpu().numpy(), self.scale.cpu().numpy(), self.weights.cpu().numpy(),
                                   float(self.intercept), float(self.alpha))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Predictions per image (N, float32, on x's device), from the images' 8-bit values."""
        return torch.from_numpy(self.floor().predict_features(image_features(x))).float().to(x.device)


def image_features(x: torch.Tensor) -> np.ndarray:
    """plumbline.line_features of every image of a batch N×C×H×W in [0, 1] (its 8-bit values back), N×FEATURES."""
    images = x.detach().float().mul(255.0).round_().clamp_(0, 255).to(torch.uint8).permute(0, 2, 3, 1).cpu().numpy()
    return plumbline.feature_matrix(np.ascontiguousarray(image) for image in images)


def build(cfg: ModelConfig) -> nn.Module:
    """The model cfg.arch names (MODELS), untrained."""
    if cfg.arch not in MODELS:
        raise TrainError(f"model must be one of {', '.join(MODELS)}, got {cfg.arch!r}")
    return {"paper": AppdNet, "patch": PatchNet, "plumbline": PlumbLineNet}[cfg.arch](cfg)
