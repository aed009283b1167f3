"""The networks `fit --model` chooses from (MODELS, build): the paper's CNN (train.model.AppdNet) and a stride-4
patchify stem that reads full-resolution detail at about a third of the paper CNN's cost at a quarter of the
resolution.

At 348×128 the bent-line signal a single image carries is under a pixel (benchmarks/visibility.py); the paper feeds
1392×512 for it, at 16× the cost. A 4×4/stride-4 convolution keeps each 4×4 patch's detail in its channels (48
inputs → `PATCH_FILTERS[0]` outputs), after which stride-2 convolutions work on a 348×128 grid.
"""
from __future__ import annotations

import torch
from torch import nn

from train.errors import TrainError
from train.model import INPUT_CHANNELS, NORMALIZE, AppdNet, ModelConfig, Normalize, Regressor

#: ModelConfig.arch → the network: the paper's CNN, or the stride-4 patchify network (PatchNet).
MODELS = ("paper", "patch")
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
        for a, b in zip(PATCH_FILTERS, PATCH_FILTERS[1:]):
            layers += [nn.Conv2d(a, b, 3, stride=2, padding=1), nn.ReLU(True)]
        self.features = nn.Sequential(*layers)
        with torch.no_grad():
            flat = self.features(torch.zeros(1, cfg.in_channels, cfg.height, cfg.width)).numel()
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(flat, PATCH_DENSE), nn.ReLU(True), nn.Dropout(cfg.dropout),
                                  nn.Linear(PATCH_DENSE, cfg.outputs))
        self.reset_parameters()


def build(cfg: ModelConfig) -> nn.Module:
    """The network cfg.arch names (MODELS), untrained."""
    if cfg.arch not in MODELS:
        raise TrainError(f"model must be one of {', '.join(MODELS)}, got {cfg.arch!r}")
    return AppdNet(cfg) if cfg.arch == "paper" else PatchNet(cfg)
