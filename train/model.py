"""The paper's CNN: 7 conv blocks, then dense 512 → 128 → 1 regressing APPD (% of diagonal); train.nets builds
it or the other networks by ModelConfig.arch."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from itertools import pairwise

import torch
from torch import nn

from train.errors import TrainError

#: Filters per block (Cramariuc et al. 2020): each block is conv3×3+ReLU, conv3×3+ReLU, maxpool 2×2.
PAPER_FILTERS: tuple[int, ...] = (32, 32, 32, 64, 128, 128, 128)
PAPER_DENSE: tuple[int, ...] = (512, 128)
#: Input normalisation: per-channel mean and std, or (the released code's) a per-pixel mean image and channel std.
NORMALIZE = ("channel", "pixel")
#: ModelConfig.channels → the network's input channels: OpenCV's BGR colour, or one grey channel (a build from a
#: mono camera: build.json's channels 1).
INPUT_CHANNELS = {"bgr": 3, "grey": 1}


@dataclass(frozen=True)
class ModelConfig:
    """Network input size (pixels), layer widths and the normalisation baked into the model."""

    width: int
    height: int
    filters: tuple[int, ...] = PAPER_FILTERS
    dense: tuple[int, ...] = PAPER_DENSE
    dropout: float = 0.5
    mean: tuple[float, ...] = (0.5, 0.5, 0.5)
    std: tuple[float, ...] = (0.25, 0.25, 0.25)
    channels: str = "bgr"
    normalize: str = "channel"
    arch: str = "paper"
    outputs: int = 1  # 1: a scalar per image (N); more: a vector per image (N×outputs, e.g. a dense field)

    def to_dict(self) -> dict:
        """Plain dict (lists, numbers, str) safe for weights_only checkpoints."""
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        """Inverse of to_dict; unknown keys are ignored so newer checkpoints still load."""
        names = set(cls.__dataclass_fields__)
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items() if k in names}
        return cls(**kw)

    @property
    def in_channels(self) -> int:
        """Channels of the input images (3 BGR, 1 grey)."""
        return INPUT_CHANNELS[self.channels]


def min_side(n_blocks: int = len(PAPER_FILTERS)) -> int:
    """Smallest image side (pixels) that survives n_blocks 2×2 max-pools with ≥ 1 pixel left."""
    return 2**n_blocks


def feature_size(width: int, height: int, n_blocks: int) -> tuple[int, int]:
    """Spatial size (w, h) left after n_blocks floor-halving max-pools."""
    for _ in range(n_blocks):
        width, height = width // 2, height // 2
    return width, height


def check_size(width: int, height: int, n_blocks: int = len(PAPER_FILTERS)) -> None:
    """Raise a clear TrainError when an image is too small for the network's poolings."""
    need = min_side(n_blocks)
    if width < need or height < need:
        raise TrainError(
            f"images are {width}x{height} px but the network's {n_blocks} 2x2 max-pools need at least "
            f"{need}x{need} px; build the shards with a larger --size"
        )


def init_relu_net(net: nn.Module, last: nn.Module) -> None:
    """Xavier-uniform weights (with the ReLU gain √2 where a ReLU follows, 1 for the output layer `last`), zero
    biases."""
    # Plain Xavier (Keras' glorot default) halves the signal's variance at every ReLU: after 16 layers the
    # output std was 2e-4 of its input's and the net sat at the mean predictor. The ReLU gain keeps it ~1.
    relu_gain = nn.init.calculate_gain("relu")
    for m in net.modules():
        if isinstance(m, (nn.Conv2d, nn.Linear)):
            nn.init.xavier_uniform_(m.weight, gain=1.0 if m is last else relu_gain)
            nn.init.zeros_(m.bias)


class Normalize(nn.Module):
    """(x − mean) / std, x in [0, 1]; buffers so exports and checkpoints carry the statistics.

    mean is per channel (1×C×1×1), or with `pixels` (H, W) a mean image 1×C×H×W, filled with the channel means
    until the trainer (or a checkpoint) sets it; std is per channel either way.
    """

    def __init__(self, mean: tuple[float, ...], std: tuple[float, ...], pixels: tuple[int, int] | None = None) -> None:
        super().__init__()
        m = torch.tensor(mean, dtype=torch.float32).view(1, -1, 1, 1)
        self.register_buffer("mean", m.expand(1, -1, *pixels).clone() if pixels else m)
        self.register_buffer("std", torch.tensor(std, dtype=torch.float32).view(1, -1, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised image batch."""
        return (x - self.mean) / self.std


def conv_block(c_in: int, c_out: int) -> nn.Sequential:
    """conv3×3 + ReLU, conv3×3 + ReLU, maxpool 2×2 ('same' padding, as in the paper's Keras model)."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1), nn.ReLU(inplace=True),
        nn.MaxPool2d(2),
    )


class Regressor(nn.Module):
    """What every network of the trainer is: `normalize`, `features` and a dense `head` ending in cfg.outputs."""

    cfg: ModelConfig

    def reset_parameters(self) -> None:
        """Xavier-uniform weights with the ReLU gain, zero biases (init_relu_net)."""
        init_relu_net(self, self.head[-1])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Predictions per image (the fit's target, % of raw diagonal): N, or N×outputs."""
        out = self.head(self.features(self.normalize(x)))
        return out.squeeze(1) if self.cfg.outputs == 1 else out


class AppdNet(Regressor):
    """Image batch N×C×H×W, float in [0, 1] (C and order from cfg.channels) → predicted APPD (% of diagonal), N."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        check_size(cfg.width, cfg.height, len(cfg.filters))
        self.cfg = cfg
        if cfg.normalize not in NORMALIZE:
            raise TrainError(f"normalize must be one of {', '.join(NORMALIZE)}, got {cfg.normalize!r}")
        if cfg.channels not in INPUT_CHANNELS:
            raise TrainError(f"channels must be one of {', '.join(INPUT_CHANNELS)}, got {cfg.channels!r}")
        self.normalize = Normalize(cfg.mean, cfg.std, (cfg.height, cfg.width) if cfg.normalize == "pixel" else None)
        chans = (cfg.in_channels, *cfg.filters)
        self.features = nn.Sequential(*(conv_block(a, b) for a, b in pairwise(chans)))
        # Flatten, not global pooling: where an error shows in the image (centre vs border) carries
        # information about distortion, and the paper flattens too. Fixes the input size to cfg's.
        fw, fh = feature_size(cfg.width, cfg.height, len(cfg.filters))
        sizes = (cfg.filters[-1] * fw * fh, *cfg.dense)
        layers: list[nn.Module] = [nn.Flatten()]
        for i, (a, b) in enumerate(pairwise(sizes)):
            layers += [nn.Linear(a, b), nn.ReLU(inplace=True)]
            if i == 0:
                layers.append(nn.Dropout(cfg.dropout))
        layers.append(nn.Linear(sizes[-1], cfg.outputs))
        self.head = nn.Sequential(*layers)
        self.reset_parameters()


