"""The trainer's one inference path: a model's predictions over batches of 8-bit images, which fit's validation,
evaluate, predict and the studies all read."""
from __future__ import annotations

from collections.abc import Iterable, Iterator

import torch

from train import runtime


def to_input(batch: dict, device: torch.device) -> torch.Tensor:
    """uint8 N×3×H×W → float [0, 1] on device, channels_last (≈2× faster convs on CPU and GPU)."""
    x = batch["image"].to(device, non_blocking=True).float().div_(255.0)
    return x.contiguous(memory_format=torch.channels_last)


def predict(model: torch.nn.Module, batches: Iterable[dict], device: torch.device, dtype: torch.dtype | None = None,
            limit: int | None = None) -> Iterator[tuple[dict, torch.Tensor]]:
    """Each batch ({"image": uint8 N×C×H×W, …}) with the model's predictions of it (float32 on `device`, N or
    N×outputs, in the fit's target units: % of the raw diagonal), in eval mode (the model's mode restored after)
    under autocast `dtype` (None: fp32); stops after the batch that brings the count to `limit` images."""
    was_training, seen = model.training, 0
    model.eval()
    try:
        for batch in batches:
            with torch.no_grad(), runtime.autocast(device, dtype):
                out = model(to_input(batch, device)).float()
            yield batch, out
            seen += len(out)
            if limit is not None and seen >= limit:
                return
    finally:
        model.train(was_training)
