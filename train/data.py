"""Split selection and a WebDataset stream over a build's shards (appdgen.dataset.shardset) split across ranks and
loader workers."""
from __future__ import annotations

import json
import random
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import torch
import webdataset as wds
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from appdgen.dataset.layout import INDEX, LABEL_COLUMN, RECORD_EXT, RECORD_FIELD
from appdgen.dataset.reader import ShardEntry as Shard
from appdgen.dataset.shardset import decode_sample, image_entry, open_shards, read_labels, target_labels
from train.errors import TrainError
from train.holdout import is_held, val_choice

#: Slots (rank × worker) may get whole shards only if their sample counts differ by at most this.
SHARD_BALANCE = 0.10


@dataclass(frozen=True)
class Selection:
    """Which samples a stream yields: one split, optionally one side of a holdout by recording or raw image."""

    split: str
    holdout: float = 0.0
    side: str = "train"  # "train" keeps the rest, "val" keeps the held-out recordings (or raw images)
    raw_paths: Mapping[str, str] | None = None
    by: str = "recording"
    held: frozenset[str] | None = None  # the held-out recordings, when known; else a hash coin per recording

    def accepts(self, meta: Mapping) -> bool:
        """True when a sample's json metadata belongs to this selection."""
        if meta.get("split") != self.split:
            return False
        if self.holdout <= 0:
            return True
        key = str(meta.get("key", ""))
        ident = str(meta.get("raw_path") or (self.raw_paths or {}).get(key) or key)
        return is_held(ident, meta.get("source"), self.by, self.held, self.holdout) == (self.side == "val")

    def describe(self) -> str:
        """Human-readable summary for logs and checkpoints."""
        if self.holdout <= 0:
            return f"split={self.split}"
        return f"split={self.split}, {self.side} side of a {self.holdout:.0%} holdout by {self.by} (hash)"


def count_selected(labels: Mapping[str, list] | None, sel: Selection) -> int | None:
    """Samples a selection yields, from labels.parquet; None when unknown."""
    if labels is None:
        return None
    sources = labels.get("source") or [None] * len(labels["key"])
    rows = zip(labels["key"], labels["split"], labels["raw_path"], sources, strict=True)
    return sum(sel.accepts({"key": k, "split": s, "raw_path": r, "source": o}) for k, s, r, o in rows)


def slot_loads(counts: list[int], slots: int) -> list[int]:
    """Samples each slot gets when shard i goes to slot i mod slots (wds split_by_node∘split_by_worker)."""
    return [sum(counts[i::slots]) for i in range(slots)]


def shard_mode_ok(counts: list[int], slots: int) -> bool:
    """Whole shards per slot only if every slot gets a near-equal share; else split sample by sample."""
    if slots == 1:
        return True
    loads = slot_loads(counts, slots)
    return min(loads) > 0 and (max(loads) - min(loads)) <= SHARD_BALANCE * max(loads)


@dataclass(frozen=True)
class StreamSpec:
    """A stream of one selection over some shards, for one rank of `world` (captured at build time)."""

    shards: tuple[Shard, ...]
    selection: Selection
    size: tuple[int, int] | None = None
    loop: bool = False
    shuffle: bool = False
    seed: int = 0
    epoch0: int = 0
    buffer: int = 256
    rank: int = 0
    world: int = 1
    force_sample_mode: bool = False
    limit: int | None = None
    skip_batches: int = 0  # batches of `batch` samples the DataLoader already delivered (a resumed run's step)
    batch: int = 1
    labels: Mapping[str, float] | None = None  # key → label (target_labels); None: the json members' appd_pct

    def skip(self, worker: int, workers: int) -> int:
        """Samples loader worker `worker` of `workers` already produced: the DataLoader takes batch j from worker
        j mod workers, whole batches from one worker, so a resumed stream continues exactly where it stopped."""
        return self.batch * max(0, -(-(self.skip_batches - worker) // workers))


class ShardStream(IterableDataset):
    """Yields {"image": uint8 3×H×W, "label": float32 (APPD %, or spec.labels'), "key": str}; each sample once per
    pass.

    Slots are (rank, worker) pairs. When the shards divide evenly among slots, each slot reads whole
    shards (as wds.split_by_node then wds.split_by_worker would); otherwise every slot reads all
    shards and keeps the accepted samples whose ordinal ≡ slot (mod slots). Either way the slots
    partition the data: no duplicates, no loss. Rank and world are taken from the spec rather than
    from torch.distributed so that spawned loader workers agree with their parent.
    """

    def __init__(self, spec: StreamSpec) -> None:
        super().__init__()
        self.spec = spec

    def slot(self) -> tuple[int, int, int]:
        """(this slot, number of slots) across ranks × loader workers, and the samples this slot skips."""
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info else (0, 1)
        # A fresh DataLoader asks worker 0 first, but batch `skip_batches` came from worker skip_batches mod
        # workers: each worker takes over the share of the one that was due, so the order continues unchanged.
        worker = (worker + self.spec.skip_batches) % workers
        return self.spec.rank * workers + worker, self.spec.world * workers, self.spec.skip(worker, workers)

    def __iter__(self) -> Iterator[dict]:
        """Passes over the data, forever when spec.loop, reshuffled each pass when spec.shuffle."""
        slot, slots, skip = self.slot()
        epoch = self.spec.epoch0
        produced = seen = 0
        while True:
            before = seen
            for item in self._one_pass(slot, slots, epoch):
                seen += 1
                if seen <= skip:
                    continue  # a resumed run's data already trained on: skipped before decoding
                yield self._decode(*item)
                produced += 1
                if self.spec.limit is not None and produced >= self.spec.limit:
                    return
            if not self.spec.loop or seen == before:  # an empty pass would spin forever
                return
            epoch += 1

    def _one_pass(self, slot: int, slots: int, epoch: int) -> Iterator[tuple[dict, str, bytes, str]]:
        """One pass of this slot's share, optionally shuffled through a buffer, still encoded."""
        spec = self.spec
        counts = [s.splits.get(spec.selection.split, 0) for s in spec.shards]
        by_shard = not spec.force_sample_mode and shard_mode_ok(counts, slots)
        shards = list(spec.shards[slot::slots] if by_shard else spec.shards)
        rng = random.Random(f"{spec.seed}/{epoch}/{slot}")
        if spec.shuffle:
            rng.shuffle(shards)  # per-slot order: fine, since the assignment is fixed above
        raw = self._accepted(shards)
        if not by_shard:
            raw = (m for i, m in enumerate(raw) if i % slots == slot)
        if spec.shuffle:
            raw = _buffer_shuffle(raw, spec.buffer, rng)
        yield from raw

    def _accepted(self, shards: list[Shard]) -> Iterator[tuple[dict, str, bytes, str]]:
        """(json, image ext, image bytes, shard path) of accepted samples, image not yet decoded."""
        urls = [{"url": str(s.path)} for s in shards]
        for sample in wds.tarfile_to_samples()(iter(urls)):
            url = sample.get("__url__", "?")
            if RECORD_FIELD not in sample:
                raise TrainError(f"{url}: sample {sample.get('__key__')} has no {RECORD_EXT} metadata")
            meta = json.loads(sample[RECORD_FIELD])
            if self.spec.selection.accepts(meta):
                ext, data = image_entry(sample)
                yield meta, ext, data, url

    def _decode(self, meta: dict, ext: str, data: bytes, url: str) -> dict:
        """Decoded, size-checked sample."""
        where = f"{url}: sample {meta.get('key')}"
        img = decode_sample(data, ext, where)
        if self.spec.size is not None and (img.shape[1], img.shape[0]) != tuple(self.spec.size):
            w, h = self.spec.size
            raise TrainError(f"{where}: image is {img.shape[1]}x{img.shape[0]}, expected {w}x{h}")
        if self.spec.labels is not None:
            label = self.spec.labels.get(str(meta.get("key")))
            if label is None:
                raise TrainError(f"{where}: not in {INDEX}")
        else:
            label = meta.get(LABEL_COLUMN)
            if label is None:
                raise TrainError(f"{where}: json has no {LABEL_COLUMN} label")
        return {
            "image": torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))),
            "label": torch.tensor(float(label), dtype=torch.float32),
            "key": str(meta.get("key", "")),
        }


def _buffer_shuffle(items: Iterator, size: int, rng: random.Random) -> Iterator:
    """Approximate shuffle with a bounded buffer (holds encoded bytes, so memory stays small)."""
    buf: list = []
    for item in items:
        if len(buf) < size:
            buf.append(item)
            continue
        i = rng.randrange(size)
        buf[i], item = item, buf[i]
        yield item
    rng.shuffle(buf)
    yield from buf


def make_loader(spec: StreamSpec, batch: int, workers: int) -> DataLoader:
    """Batched DataLoader over a ShardStream (workers decode; batches stay uint8 until the device)."""
    return DataLoader(
        ShardStream(spec),
        batch_size=batch,
        num_workers=workers,
        persistent_workers=False,
        pin_memory=torch.cuda.is_available(),
        prefetch_factor=4 if workers > 0 else None,
    )


def build_val_loader(root: str, val_split: str, target: str, size: tuple[int, int], batch: int, workers: int
                     ) -> DataLoader:
    """Validation batches of another build (fit --online --val-shards): --val-split when it names a split, else the
    build's val split, else its first."""
    ss = open_shards(root)
    split = val_choice(val_split, ss.split_count("val") > 0)
    if split in ("holdout", "none"):  # no holdout of another build: its val split, else its first
        split = "val" if ss.split_count("val") else next(iter(ss.build.get("counts", {}).get("splits", {})), "val")
    labels = target_labels(read_labels(ss.root, target), target)
    return make_loader(StreamSpec(ss.for_split(split), Selection(split), size, labels=labels), batch, workers)


def channel_stats(spec: StreamSpec, n: int, n_total: int | None
                  ) -> tuple[list[float], list[float], list[float], np.ndarray]:
    """Per-channel mean and std of pixels in [0, 1] over ~n samples spread evenly, their labels, and the
    per-pixel mean image (C×H×W float32)."""
    stride = max(1, (n_total or n) // n)
    # A 'world' of `stride` ranks in sample mode picks every stride-th sample: spread, not the first n.
    sub = StreamSpec(spec.shards, spec.selection, spec.size, world=stride, force_sample_mode=True, limit=n,
                     labels=spec.labels)
    stats = PixelStats()
    labels: list[float] = []
    for sample in ShardStream(sub):
        stats.add(sample["image"].numpy()[None])
        labels.append(float(sample["label"]))
    if not stats.count:
        raise TrainError(f"no samples for {spec.selection.describe()} in {len(spec.shards)} shard(s)")
    mean, std, mean_image = stats.result()
    return mean, std, labels, mean_image


class PixelStats:
    """Running per-channel mean and std of 8-bit images (N×C×H×W) as pixels in [0, 1], and their mean image."""

    def __init__(self) -> None:
        self.image_sum: np.ndarray | None = None
        self.square_sum: np.ndarray | float = 0.0
        self.count = 0

    def add(self, images: np.ndarray) -> None:
        """Count a batch of images (N×C×H×W, 0…255)."""
        img = images.astype(np.float64) / 255.0
        total = img.sum(0)
        self.image_sum = total if self.image_sum is None else self.image_sum + total
        self.square_sum = self.square_sum + (img**2).reshape(*img.shape[:2], -1).sum((0, 2))
        self.count += len(img)

    def result(self) -> tuple[list[float], list[float], np.ndarray]:
        """(mean per channel, std per channel ≥ 1e-3, the mean image C×H×W float32)."""
        mean_image = self.image_sum / self.count
        pixels = self.count * mean_image[0].size
        mean = mean_image.reshape(mean_image.shape[0], -1).mean(1)
        std = np.sqrt(np.maximum(self.square_sum / pixels - mean**2, 1e-12))
        return mean.tolist(), np.maximum(std, 1e-3).tolist(), mean_image.astype(np.float32)
