"""`fit --model plumbline`: the plumb-line floor's closed-form fit, beside the training loop (train.loop.Trainer)
on the same data, validation, log and checkpoints: line features of the training batches, one ridge (alpha by
cross-validation), no gradient steps."""
from __future__ import annotations

import sys
import time

import numpy as np

from appdgen.util.progress import Progress
from train.errors import TrainError
from train.inference import to_input
from train.loop import Deadline, Trainer
from train.nets import image_features
from train.plumbline import PlumbLine


def fit_closed_form(trainer: Trainer, steps: int) -> dict:
    """Fit the trainer's closed-form model on `steps` batches of its training images (fewer when --max-minutes
    runs out), validate and save it; fit's summary (train_loss: MSE on the training images, the target's %²)."""
    done = trainer.finished(steps)
    if done is not None:
        return done
    if trainer.world > 1:
        raise TrainError(f"--model {trainer.model.cfg.arch} fits in one process: run it without torchrun")
    trainer.announce(0, steps)
    start = time.perf_counter()
    x, y, batches = training_features(trainer, steps)
    floor = PlumbLine().fit_features(x, y, alpha=None)
    trainer.model.set_floor(floor)
    trainer.trained += (len(y), time.perf_counter() - start)
    loss = float(np.mean((floor.predict_features(x) - y) ** 2))
    val = trainer.validate(batches)
    trainer.log.row(step=batches, train_loss=loss, images_per_s=trainer.trained.rate(), **val)
    trainer.save(batches)
    return trainer.summary(batches, loss, val)


def training_features(trainer: Trainer, steps: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(line features N×FEATURES, targets N, batches read) of up to `steps` training batches, fewer when
    --max-minutes runs out."""
    opts = trainer.opts
    progress = Progress(steps, "batches", enabled=not opts.quiet, every=30.0)
    batches, deadline = trainer.loader(0), Deadline(opts.max_minutes)
    features: list[np.ndarray] = []
    targets: list[np.ndarray] = []
    while len(features) < steps:
        batch = next(batches, None)
        if batch is None:
            raise TrainError(f"no training samples for {trainer.plan.training()}")
        features.append(image_features(to_input(batch, trainer.device)))
        targets.append(batch["label"].numpy().astype(float).ravel())
        progress.update(len(features), f"fit: line features of {sum(map(len, targets))} images")
        if len(features) % opts.log_every == 0 and deadline.passed():
            print(f"\nfit: --max-minutes {opts.max_minutes:g} reached; fitting on {len(features)} batches",
                  file=sys.stderr)
            break
    progress.close()
    return np.concatenate(features), np.concatenate(targets), len(features)
