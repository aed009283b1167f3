"""The detector comparison (issue 23): networks and targets side by side on the same fresh pairs, scored on the
axes of novelty that tell memorisation from generalisation.

Arms (ARMS): the paper's CNN at low resolution (348×128 for KITTI), the stride-4 patch network (train.nets) at
full resolution, the patch network on a dense target (the warp's displacement and its non-affine rest on a coarse
grid, geometry.bend.warp_field; APPD and bend read off it), and the classical plumb-line floor
(train.plumbline); the networks on `appd` and on `bend` (geometry.bend.split_warp, % of the raw diagonal).
The bend-field estimator (appdgen.detect's Detector, no training) is scored on the same axes, draws and metrics by
studies/bendfield.py (python -m studies.bendfield), which reads the raw frames under each draw as the belief.

Every network arm of a stream sees the same images in the same order: image i of the run is fit --online's pair
i (train.online.pairs: draw(seed, i) of the build sampler, frame frame_of(seed, i)); each arm is a fit of the
trainer's one loop (train.loop.Trainer, saved by train.checkpoint to OUT/STREAM-MODEL-TARGET/last.pt), the arms one
after the other; the low and full streams draw with the same seeds from the same synthetic streets (synth frame i
depends on (seed, i) only, at any scale). The number of training images is fixed, not the minutes.

Axes (each S sequences of L frames, one fixed-seed miscalibration per sequence, the same S on every synthetic
axis): `views`, the training frames under other miscalibrations (memorisation); `viewpoint`, the training streets
from a camera moved sideways (appdgen synth --offset); `unseen`, streets of another seed; `real`, real frames in
recording order (given; with --finetune N, after the first N, whose pairs join the floor's fit). Frames are read
through appdgen.sources; the pairs, the test sequences and their metrics are the trainer's (train.scoring), so that
`python -m train evaluate --frames` scores as this table does.

    python -m studies.detector [--tiny] [--images 4000] [--frames 300] [--sequences 16] [--out runs/detector]
    python -m studies.detector --calib ../shared/data/real/euroc_micro_cam1/sensor.yaml \\
        --real ../shared/data/real/euroc_micro_cam1/data --low-scale 0.5 --grey   # sim-to-real

Prints one markdown table and a JSON line with the command, the CPU seconds and the load average.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from appdgen.errors import AppdgenError
from appdgen.geometry.appd import px_to_pct
from appdgen.sources.frames import RawImage
from train.loop import Trainer  # torch: every study here fits networks
from train.scoring import LABELS, SEQUENCE_SEED, make_pairs, sequence_metrics, sequence_pairs

ROOT = Path(__file__).resolve().parents[1]
#: What a network regresses: APPD or bend (one value, % of diagonal) or the dense field (FIELD_COLUMNS grid).
TARGETS = ("appd", "bend", "field")
#: Grid columns of the dense target (rows in the raw aspect, at least 4: 12 × 4 at KITTI's): 4 values a point.
FIELD_COLUMNS = 12
#: The two image streams: the paper's quarter-size input and the full raw resolution.
STREAMS = ("low", "full")
#: The synthetic axes (views, viewpoint, unseen) all draw train.scoring's test sequences (sequence k under draw
#: (SEQUENCE_SEED, k)), so differences between those axes are the scenes only.
#: Draw seeds of the test axes (fixed: every run tests on the same miscalibrations), and the recalibration pairs'.
AXIS_SEEDS = {"views": SEQUENCE_SEED, "viewpoint": SEQUENCE_SEED, "unseen": SEQUENCE_SEED, "real": 7004}
RECAL_SEED = 7005
#: Draw seed of the pairs of the first real frames the floor is fine-tuned on (--finetune).
TUNE_SEED = 7006
#: Synth seed offsets: the training streets and the unseen ones.
TRAIN_SYNTH, TEST_SYNTH = 101, 202
#: Rendering interpolation: bicubic, 3.4× cheaper than Lanczos at 1392×512 (docs/studies/online-vs-offline.md), as
#: paper-scale's.
INTERP = "cubic"


@dataclass(frozen=True)
class Arm:
    """One arm: a model (train.nets.MODELS, or "plumbline"), its target, the stream it sees."""

    model: str
    target: str
    stream: str

    @property
    def name(self) -> str:
        """e.g. patch/field."""
        return f"{self.model}/{self.target}"


ARMS = (Arm("paper", "appd", "low"), Arm("paper", "bend", "low"), Arm("patch", "appd", "full"),
        Arm("patch", "bend", "full"), Arm("patch", "field", "full"), Arm("plumbline", "appd", "full"),
        Arm("plumbline", "bend", "full"))


@dataclass(frozen=True)
class DetectorOptions:
    """Sizes of the comparison; `images` is per arm (every network arm trains on that many fresh pairs)."""

    out: str = "runs/detector"
    calib: str | None = None  # default: the bundled KITTI 02
    camera: str | None = None
    real: str | None = None  # a folder of real frames of that camera: the `real` axis
    low_scale: float = 0.25
    frames: int = 300  # training streets
    sequences: int = 16  # per axis
    length: int = 10  # frames per sequence
    offset: float = 0.3  # metres: the viewpoint axis
    images: int = 4000
    batch: int = 16
    lr: float = 3e-4
    stats: int = 128  # first images of the run: input normalisation and target standardisation
    recal: int = 256  # fresh training pairs after training: each network's least-squares output line
    floor_images: int = 300
    finetune: int = 0  # first real frames: floor_images pairs of them join the floor's fit, the real axis follows
    seed: int = 0
    device: str = "cpu"
    jobs: int = 2
    grey: bool = False  # synth frames made grey (a mono real camera)
    arms: tuple[str, ...] = tuple(a.name for a in ARMS)


TINY = dict(frames=24, sequences=2, length=4, images=48, batch=8, stats=16, recal=16, floor_images=16)


# --- frames ---------------------------------------------------------------------------------------------


def reference(o: DetectorOptions):
    """The full-size reference calibration (KITTI 02 unless --calib)."""
    from appdgen.calib.defaults import DEFAULT_CALIB_PATH
    from appdgen.calib.formats import load

    return load(o.calib or str(DEFAULT_CALIB_PATH), o.camera or (None if o.calib else "02"))


def stream_scale(o: DetectorOptions, stream: str) -> float:
    """Synth scale of a stream."""
    return o.low_scale if stream == "low" else 1.0


def synth_all(o: DetectorOptions) -> None:
    """OUT/raw/{low,full}/{train,viewpoint,unseen}: the same streets at both scales (reused when complete), for
    the streams the run's arms use."""
    from appdgen.synth import CAR, synthesize

    calib, test = reference(o), o.sequences * o.length
    for stream in (s for s in STREAMS if any(a.stream == s and a.name in o.arms for a in ARMS)):
        for folder, count, seed, mount in (("train", o.frames, TRAIN_SYNTH + o.seed, CAR),
                                           ("viewpoint", test, TRAIN_SYNTH + o.seed, replace(CAR, offset=o.offset)),
                                           ("unseen", test, TEST_SYNTH + o.seed, CAR)):
            where = Path(o.out) / "raw" / stream / folder
            if len(listed(where)) != count:
                synthesize(calib, count, where, seed, stream_scale(o, stream), jobs=o.jobs, mount=mount)


def listed(folder: Path) -> list[RawImage]:
    """A folder's images in name order (appdgen.sources.files.list_images, recursive); [] when it has none."""
    from appdgen.sources.files import list_images

    try:
        return list_images(str(folder))
    except AppdgenError:  # no such folder, or no images in it yet
        return []


def load_frames(images: list[RawImage], grey: bool, scale: float = 1.0) -> np.ndarray:
    """N×H×W×3 uint8 BGR frames read through appdgen.sources (grey replicated when `grey`; INTER_AREA-resized by
    `scale`)."""
    import cv2

    from appdgen.sources.decode import as_channels
    from appdgen.sources.inputs import iter_images

    out = []
    for image in iter_images(images, 1 if grey else 3):
        image = as_channels(image, 3)
        out.append(image if scale == 1.0 else cv2.resize(image, None, fx=scale, fy=scale,
                                                         interpolation=cv2.INTER_AREA))
    return np.stack(out)


def recording(o: DetectorOptions) -> list[RawImage]:
    """The real frames in recording order (file names sort by time stamp); [] without --real."""
    return listed(Path(o.real)) if o.real and Path(o.real).is_dir() else []


def real_frames(o: DetectorOptions) -> list[RawImage]:
    """The real axis's frames: those after the --finetune ones, whole sequences, S·L of them at most."""
    found = recording(o)[o.finetune:]
    return found[: (len(found) // o.length) * o.length][: o.sequences * o.length]


def tune_frames(o: DetectorOptions) -> list[RawImage]:
    """The first --finetune real frames: the floor's real training frames, never tested on."""
    return recording(o)[:o.finetune]


# --- pairs and targets ----------------------------------------------------------------------------------


@dataclass
class Stream:
    """One resolution's scene (train.online.recipe.PairRecipe: reference, size, sampling) and its frames per
    folder."""

    scene: object
    frames: dict[str, np.ndarray] = field(default_factory=dict)


def open_stream(o: DetectorOptions, stream: str) -> Stream:
    """The scene at a stream's scale and its frames decoded (train, viewpoint, unseen, real)."""
    from appdgen.sampling.options import DEFAULT_ZERO_FRACTION, SamplingOptions
    from appdgen.sampling.sampler import DEFAULT_APPD_MAX
    from appdgen.synth import scale_calibration
    from train.online.recipe import PairRecipe

    scale = stream_scale(o, stream)
    ref = scale_calibration(reference(o), scale)
    sampling = SamplingOptions.parse(ref, None, DEFAULT_APPD_MAX, DEFAULT_ZERO_FRACTION, None, INTERP)
    s = Stream(PairRecipe(ref, o.camera or "02", ref.size, sampling))
    raw = Path(o.out) / "raw" / stream
    for folder in ("train", "viewpoint", "unseen"):
        s.frames[folder] = load_frames(listed(raw / folder), o.grey)
    for folder, paths in (("real", real_frames(o)), ("tune", tune_frames(o))):
        if paths:
            s.frames[folder] = load_frames(paths, True, scale)
    return s


def field_label(scene, draw) -> np.ndarray:
    """The dense target of a draw: FIELD_COLUMNS grid × (moved x, y, rest x, y), % of the raw diagonal."""
    from appdgen.geometry.bend import warp_field

    f = warp_field(scene.reference, scene.sampler().reference_rect.crop, draw.calib, draw.rect.crop, FIELD_COLUMNS)
    return px_to_pct(np.concatenate([f.moved, f.rest], axis=1).ravel(), scene.reference)


#: Every target of the comparison: the trainer's labels (appd, bend) and the dense field.
PAIR_LABELS = {**LABELS, "field": field_label}


def train_pairs(s: Stream, seed: int, first: int, count: int) -> dict:
    """fit --online's pairs first … first + count − 1 of a run with this seed, on the stream's training frames."""
    from train.online.pairs import frame_of

    n = len(s.frames["train"])
    ids = range(first, first + count)
    return make_pairs(s.scene, s.frames["train"], [(seed, i) for i in ids], [frame_of(seed, i, n) for i in ids],
                      PAIR_LABELS)


def axis_pairs(s: Stream, axis: str, o: DetectorOptions) -> dict:
    """An axis's test pairs: sequence_pairs of its folder under AXIS_SEEDS[axis]."""
    folder = {"views": "train", "viewpoint": "viewpoint", "unseen": "unseen", "real": "real"}[axis]
    return sequence_pairs(s.scene, s.frames[folder], AXIS_SEEDS[axis], o.sequences, o.length, PAIR_LABELS)


def axes(o: DetectorOptions) -> list[str]:
    """The axes this run reports (real only with real frames)."""
    return ["views", "viewpoint", "unseen"] + (["real"] if real_frames(o) else [])


# --- networks: fits of the trainer's one loop -------------------------------------------------------------


class ArmTrainer(Trainer):
    """One network arm's fit, through the trainer's loop: o.images fresh pairs of the stream in batches of o.batch,
    its target standardised by the first o.stats pairs (which also give the input normalisation); saved by
    train.checkpoint to `run`."""

    def __init__(self, arm: Arm, s: Stream, o: DetectorOptions, device, run: Path) -> None:
        from train import checkpoint
        from train.data import PixelStats
        from train.model import ModelConfig
        from train.online.trainer import OnlinePlan
        from train.options import FitOptions

        first = train_pairs(s, o.seed, 0, o.stats)
        stats = PixelStats()
        stats.add(first["image"])
        mean, std, _ = stats.result()
        y = first[arm.target].reshape(len(first["image"]), -1)
        self.arm, self.stream, self.o, self.data_s = arm, s, o, 0.0
        self.mean, self.std = y.mean(0), np.maximum(y.std(0), 1e-3)
        self.label_mean = {t: float(first[t].mean()) for t in ("appd", "bend")}
        _, _, h, w = first["image"].shape
        cfg = ModelConfig(w, h, mean=tuple(mean), std=tuple(std), arch=arm.model,
                          outputs=y.shape[1] if arm.target == "field" else 1)
        steps = math.ceil(o.images / o.batch)
        opts = FitOptions(shards=None, run=str(run), steps=steps, batch=o.batch, lr=o.lr, ckpt_every=steps,
                          log_every=max(1, steps // 10), seed=o.seed, device=o.device, model=arm.model, quiet=True)
        shutil.rmtree(run, ignore_errors=True)  # log.csv is appended to: a fresh run starts without one
        run.mkdir(parents=True)
        state = checkpoint.initial(cfg, o.seed, {"study": "detector", "arm": arm.name, "stream": arm.stream})
        super().__init__(opts, OnlinePlan(f"{arm.stream} pairs", None, o.images, None), state, device, 0, 1, run)

    def loader(self, step: int):
        """Batches step … of the run's pairs, the target standardised (timed in data_s)."""
        import torch

        o, target = self.o, self.arm.target
        for j in range(step, self.opts.steps):
            t0 = time.process_time()
            pairs = train_pairs(self.stream, o.seed, j * o.batch, min(o.batch, o.images - j * o.batch))
            y = torch.from_numpy(((pairs[target].reshape(len(pairs["image"]), -1) - self.mean) / self.std)
                                 .astype(np.float32))
            self.data_s += time.process_time() - t0
            yield {"image": torch.from_numpy(pairs["image"]), "label": y if target == "field" else y[:, 0]}

    def announce(self, step: int, steps: int) -> None:
        """One stderr line: which arm trains on how many pairs."""
        print(f"detector {self.arm.stream}: {self.arm.name} on {self.o.images} pairs, {steps} steps of "
              f"{self.o.batch}", file=sys.stderr)


def read_off(trainer, images: np.ndarray, batch: int = 32) -> dict[str, np.ndarray]:
    """An arm's raw read-offs per target: the scalar output, or the field's mean moved and rest lengths."""
    import torch

    from train.inference import predict

    chunks = ({"image": torch.from_numpy(images[i:i + batch])} for i in range(0, len(images), batch))
    out = predict(trainer.model, chunks, trainer.device, trainer.dtype)
    y = np.concatenate([p.cpu().numpy().reshape(len(p), -1) for _, p in out]) * trainer.std + trainer.mean
    if trainer.arm.target != "field":
        return {trainer.arm.target: y[:, 0]}
    points = y.reshape(len(y), -1, 4)
    return {"appd": np.hypot(points[..., 0], points[..., 1]).mean(1),
            "bend": np.hypot(points[..., 2], points[..., 3]).mean(1)}


def output_line(trainer, pairs: dict) -> dict[str, tuple[float, float]]:
    """Least-squares line (intercept, slope) from read-off to target on fresh training pairs, per target (a dense
    read-off is biased low)."""
    line = {}
    for t, r in read_off(trainer, pairs["image"]).items():
        slope, intercept = np.polyfit(r, pairs[t], 1) if np.std(r) > 0 else (0.0, float(pairs[t].mean()))
        line[t] = (float(intercept), float(slope))
    return line


def logged_losses(run: Path) -> tuple[float, float]:
    """The first and the last logged training loss of a fit (run/log.csv: a tenth of the steps each)."""
    with open(run / "log.csv", newline="") as fh:
        losses = [float(r["train_loss"]) for r in csv.DictReader(fh) if r["train_loss"]]
    return losses[0], losses[-1]


def floor_arms(arms: list[Arm], s: Stream, o: DetectorOptions, tests: dict[str, dict]) -> dict:
    """The plumb-line floor's predictions per axis and target (ridge fit on the first training pairs) and, with
    --finetune, the same fit with pairs of the first real frames added (arm plumbline+realN)."""
    from train.plumbline import PlumbLine, feature_matrix

    def features(pairs: dict) -> np.ndarray:
        """Line features of every pair's image (computed once, shared by both targets and every fit)."""
        return feature_matrix(pairs["image"].transpose(0, 2, 3, 1))

    start = time.process_time()
    pairs = train_pairs(s, o.seed, 0, o.floor_images)
    fits = [("plumbline", features(pairs), pairs)]
    if "tune" in s.frames:
        n = len(s.frames["tune"])
        tune = make_pairs(s.scene, s.frames["tune"], [(TUNE_SEED, i) for i in range(o.floor_images)],
                          [i % n for i in range(o.floor_images)], PAIR_LABELS)
        fits.append((f"plumbline+real{n}", np.vstack([fits[0][1], features(tune)]),
                     {t: np.concatenate([pairs[t], tune[t]]) for t in ("appd", "bend")}))
    tested = {axis: features(t) for axis, t in tests.items()}
    out = {}
    for arm in arms:
        for model, x, labels in fits:
            floor = PlumbLine().fit_features(x, labels[arm.target])
            out[f"{model}/{arm.target}"] = {"label_mean": float(labels[arm.target].mean()), "predictions": {
                axis: {arm.target: floor.predict_features(z).tolist()} for axis, z in tested.items()},
                "cpu_s": time.process_time() - start}
    return out


def run_stream(o: DetectorOptions, stream: str) -> dict:
    """Fit every network arm of one stream on the same pairs (one after the other), fit their output lines,
    predict every axis; the floor's arms beside them."""
    import torch

    from train import runtime

    device = runtime.pick_device(o.device)
    arms = [a for a in ARMS if a.stream == stream and a.name in o.arms]
    s = open_stream(o, stream)
    start, trainers = time.process_time(), []
    for a in (a for a in arms if a.model != "plumbline"):
        trainer = ArmTrainer(a, s, o, device, Path(o.out) / f"{stream}-{a.name.replace('/', '-')}")
        trainer.train(trainer.opts.steps)
        trainers.append(trainer)
    train_s = time.process_time() - start
    recal = train_pairs(s, RECAL_SEED, 0, o.recal)
    tests = {axis: axis_pairs(s, axis, o) for axis in axes(o)}
    result = {"stream": stream, "size": list(s.scene.size), "threads": torch.get_num_threads(),
              "train_cpu_s": train_s, "data_cpu_s": sum(t.data_s for t in trainers), "images": o.images, "arms": {},
              "truth": {axis: {t: tests[axis][t].tolist() for t in ("appd", "bend")} for axis in tests}}
    for t in trainers:
        line = output_line(t, recal)
        first_loss, last_loss = logged_losses(t.run)
        result["arms"][t.arm.name] = {
            "label_mean": t.label_mean[t.arm.target] if t.arm.target != "field" else t.label_mean,
            "line": line, "first_loss": first_loss, "last_loss": last_loss,
            "predictions": {axis: {k: (line[k][0] + line[k][1] * r).tolist()
                                   for k, r in read_off(t, pairs["image"]).items()} for axis, pairs in tests.items()}}
    result["arms"].update(floor_arms([a for a in arms if a.model == "plumbline"], s, o, tests))
    return result


# --- the table ----------------------------------------------------------------------------------------


def rows(results: list[dict], o: DetectorOptions) -> list[dict]:
    """One row per arm × target × axis."""
    out = []
    for r in results:
        for name, a in r["arms"].items():
            for axis, per_target in a["predictions"].items():
                truth = r["truth"][axis]
                for t, pred in per_target.items():
                    mean = a["label_mean"][t] if isinstance(a["label_mean"], dict) else a["label_mean"]
                    out.append({"arm": name, "target": t, "axis": axis, "stream": r["stream"],
                                "size": "x".join(map(str, r["size"])),
                                **sequence_metrics(np.array(pred), np.array(truth[t]), np.array(truth["appd"]),
                                                   mean, o.length)})
    return out


def table(found: list[dict]) -> str:
    """The rows as a markdown table."""
    lines = ["| arm | target | size | axis | MAE / mean (± SE over sequences) | ρ | AUC @0.5 % | seq mean / mean | "
             "seq median / mean |",
             "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in found:
        lines.append(f"| {r['arm']} | {r['target']} | {r['size']} | {r['axis']} | "
                     f"{r['ratio']:.2f} ± {r['ratio_se']:.2f} | "
                     f"{r['rho']:.2f} | {r['auc']:.2f} | {r['seq_mean']:.2f} | {r['seq_median']:.2f} |")
    return "\n".join(lines)


# --- the run --------------------------------------------------------------------------------------------


def run(o: DetectorOptions, parallel: bool = True) -> dict:
    """Synthesize (once), run both streams (two processes, one core each, on CPU when `parallel`), score."""
    import subprocess

    out = Path(o.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "options.json").write_text(json.dumps(asdict(o), indent=1))
    start = time.perf_counter()
    synth_all(o)
    synth_s = time.perf_counter() - start
    streams = [s for s in STREAMS if any(a.stream == s and a.name in o.arms for a in ARMS)]
    if parallel and o.device == "cpu":
        cores = sorted(os.sched_getaffinity(0))
        # -m studies.detector from anywhere: the repository's root on the children's path
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH"))))}
        procs = [subprocess.Popen([sys.executable, "-m", "studies.detector", "--child", str(out / "options.json"), s,
                                   str(cores[i % len(cores)])], env=env) for i, s in enumerate(streams)]
        if any(p.wait() for p in procs):
            raise RuntimeError("a detector stream failed (see its stderr above)")
    else:
        for s in streams:
            (out / f"{s}.part.json").write_text(json.dumps(run_stream(o, s)))
    results = [merged(out, s) if s in streams else json.loads((out / f"{s}.json").read_text())
               for s in STREAMS if s in streams or (out / f"{s}.json").exists()]
    found = rows(results, o)
    summary = {"rows": found, "synth_s": synth_s, "wall_s": time.perf_counter() - start,
               "streams": {r["stream"]: {k: r[k] for k in ("size", "threads", "train_cpu_s", "data_cpu_s", "images")}
                           | {"losses": {n: (a.get("first_loss"), a.get("last_loss")) for n, a in r["arms"].items()}}
                           for r in results}}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def merged(out: Path, stream: str) -> dict:
    """OUT/STREAM.json with this run's arms (STREAM.part.json) added: arms run later (e.g. the floor) join the
    earlier ones' table when they saw the same test pairs."""
    part = json.loads((out / f"{stream}.part.json").read_text())
    whole = out / f"{stream}.json"
    if whole.exists():
        before = json.loads(whole.read_text())
        if before["truth"] == part["truth"] and before["size"] == part["size"]:
            part["arms"] = {**before["arms"], **part["arms"]}
            for key in ("train_cpu_s", "data_cpu_s", "images", "threads"):
                part.setdefault("earlier", {})[key] = before[key]
    whole.write_text(json.dumps(part))
    (out / f"{stream}.part.json").unlink()
    return part


def child(options: str, stream: str, core: int) -> None:
    """One stream in its own process, pinned to one core (torch and OpenCV on one thread)."""
    import cv2
    import torch

    os.sched_setaffinity(0, {core})
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    o = DetectorOptions(**{k: tuple(v) if isinstance(v, list) else v for k, v in
                           json.loads(Path(options).read_text()).items()})
    result = run_stream(o, stream)
    (Path(o.out) / f"{stream}.part.json").write_text(json.dumps(result))


def options(argv: list[str] | None = None) -> DetectorOptions:
    """DetectorOptions from the command line (--tiny: TINY's sizes where not given)."""
    parser = argparse.ArgumentParser(prog="python -m studies.detector", description=__doc__.splitlines()[0])
    parser.add_argument("--tiny", action="store_true", help="All arms in a few minutes on 2 cores: the chain only.")
    parser.add_argument("--arms", help="Comma-separated arm names (default: all), e.g. paper/appd,patch/field.")
    for f in fields(DetectorOptions):
        if f.name == "arms":
            continue
        flag = "--" + f.name.replace("_", "-")
        if f.type == "bool":
            parser.add_argument(flag, action="store_true")
        else:
            parser.add_argument(flag, type={"int": int, "float": float}.get(f.type, str), default=None)
    args = parser.parse_args(argv)
    given = {f.name: getattr(args, f.name) for f in fields(DetectorOptions)
             if f.name != "arms" and getattr(args, f.name) not in (None, False)}
    o = DetectorOptions(**given)
    if args.tiny:
        o = replace(o, **{k: v for k, v in TINY.items() if k not in given})
    return replace(o, arms=tuple(args.arms.split(","))) if args.arms else o


def main(argv: list[str] | None = None) -> dict:
    """Run the comparison and print its table and a JSON line."""
    argv = sys.argv[1:] if argv is None else argv
    o = options(argv)
    load_before = os.getloadavg()
    summary = run(o)
    print(table(summary["rows"]))
    print(json.dumps({"command": " ".join(["python", "-m", "studies.detector", *argv]),
                      "wall_s": round(summary["wall_s"]), "synth_s": round(summary["synth_s"]),
                      "load_before": load_before, "load_after": os.getloadavg(), "streams": summary["streams"]}))
    return summary


if __name__ == "__main__":
    if sys.argv[1:2] == ["--child"]:  # one stream of run(): options file, stream, core
        child(sys.argv[2], sys.argv[3], int(sys.argv[4]))
    else:
        main()
