"""What the training loop is given: fit's options (FitOptions) and the Plan protocol its data plans follow (the
offline fit's DataPlan, the online fit's OnlinePlan, a study's)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from train.online.options import OnlineOptions


@dataclass(frozen=True)
class FitOptions:
    """Everything `python -m train fit` takes; stored in the checkpoint as plain values."""

    shards: str | None  # an offline build; None with `online`
    run: str
    split: str = "train"
    val_split: str = "auto"  # a split name, "auto" (val if present, else holdout) or "none"
    val_fraction: float = 0.1  # recordings (or raw images) held out by hash when there is no val split
    val_by: str = "recording"  # what the holdout keeps whole: "recording" (KITTI drive, else folder) or "image"
    steps: int | None = None
    epochs: float | None = None
    batch: int = 32
    lr: float = 1e-4
    workers: int = 1
    ckpt_every: int = 200
    val_every: int | None = None  # default: every checkpoint
    val_max: int = 1000
    log_every: int = 10
    max_minutes: float | None = None  # stop early (checkpointed, validated) after this wall time
    shuffle_buffer: int = 1000
    resume: bool = False
    seed: int = 0
    device: str = "auto"
    precision: str = "auto"
    stats_samples: int = 256
    normalize: str = "channel"  # "channel": per-channel mean/std; "pixel": a per-pixel mean image, channel std
    target: str = "appd"  # what the network learns (layout.TARGETS): appd_pct, the paper's, or bend_pct
    model: str = "paper"  # the network (train.nets.MODELS)
    quiet: bool = False
    online: "OnlineOptions | None" = None  # train on fresh pairs drawn as it goes (train.online), not shards


class Plan(Protocol):
    """What the training loop reads of a run's data plan: what trains (in words, for messages) and what validates
    (None: nothing does)."""

    @property
    def val(self) -> object | None:
        """The validation set, or None."""
        ...

    def training(self) -> str:
        """What trains, in words."""
        ...
