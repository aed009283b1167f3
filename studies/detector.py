"""The detector comparison (issue 23): networks and targets side by side on the same fresh pairs, scored on the
axes of novelty that tell memorisation from generalisation.

Arms (ARMS): the paper's CNN at low resolution (348×128 for KITTI), the stride-4 patch network (train.nets) at
full resolution, the patch network on a dense target (the warp's displacement and its non-affine rest on a coarse
grid, geometry.bend.warp_field; APPD and bend read off it), and the classical plumb-line floor (train.plumbline,
when present); the networks on `appd` and on `bend` (geometry.bend.split_warp, % of the raw diagonal).

Every network arm of a stream sees the same images in the same order: image i of the run is fit --online's pair
i (train.online.pairs: draw(seed, i) of the build sampler, frame frame_of(seed, i)), rendered once per stream and fed to
each arm in turn; the low and full streams draw with the same seeds from the same synthetic streets (synth frame i
depends on (seed, i) only, at any scale). The number of training images is fixed, not the minutes.

Axes (each S sequences of L frames, one fixed-seed miscalibration per sequence, the same S on every synthetic
axis): `views`, the training frames under other miscalibrations (memorisation); `viewpoint`, the training streets
from a camera moved sideways (appdgen synth --offset); `unseen`, streets of another seed; `real`, real frames in
recording order (given; with --finetune N, after the first N, whose pairs join the floor's fit).
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from appdgen.analysis.studies import spearman  # ties share their mean rank; nan when a side is constant
from appdgen.geometry.appd import px_to_pct

#: What a network regresses: APPD or bend (one value, % of diagonal) or the dense field (FIELD_COLUMNS grid).
TARGETS = ("appd", "bend", "field")
#: Grid columns of the dense target (rows in the raw aspect, at least 4: 12 × 4 at KITTI's): 4 values a point.
FIELD_COLUMNS = 12
#: The two image streams: the paper's quarter-size input and the full raw resolution.
STREAMS = ("low", "full")
#: Draw seed of the synthetic axes' sequences: views, viewpoint and unseen all draw the same miscalibrations (sequence
#: k under draw (SEQUENCE_SEED, k)), so differences between those axes are the scenes only. It is unseen's former
#: seed: the unseen pairs did not change when the axes stopped drawing their own (7001, 7002).
SEQUENCE_SEED = 7003
#: Draw seeds of the test axes (fixed: every run tests on the same miscalibrations), and the recalibration pairs'.
AXIS_SEEDS = {"views": SEQUENCE_SEED, "viewpoint": SEQUENCE_SEED, "unseen": SEQUENCE_SEED, "real": 7004}
RECAL_SEED = 7005
#: Draw seed of the pairs of the first real frames the floor is fine-tuned on (--finetune).
TUNE_SEED = 7006
#: Synth seed offsets: the training streets and the unseen ones.
TRAIN_SYNTH, TEST_SYNTH = 101, 202
THRESHOLD = 0.5  # % APPD: the detection threshold whose AUC is reported
#: Rendering interpolation: bicubic, 3.4× cheaper than Lanczos at 1392×512 (docs/training.md), as paper-scale's.
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
            if len(list(where.glob("frame_*.png"))) != count:
                synthesize(calib, count, where, seed, stream_scale(o, stream), jobs=o.jobs, mount=mount)


def load_frames(paths: list[Path], grey: bool, scale: float = 1.0) -> np.ndarray:
    """N×H×W×3 uint8 BGR frames (grey replicated when `grey`; INTER_AREA-resized by `scale`)."""
    import cv2

    from appdgen.sources.decode import read_image

    out = []
    for path in paths:
        image = read_image(path)
        if scale != 1.0:
            image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        if grey:
            image = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
        out.append(image)
    return np.stack(out)


def recording(o: DetectorOptions) -> list[Path]:
    """The real frames in recording order (file names sort by time stamp); [] without --real."""
    if not o.real or not Path(o.real).is_dir():
        return []
    return sorted(Path(o.real).rglob("*.png"))


def real_frames(o: DetectorOptions) -> list[Path]:
    """The real axis's frames: those after the --finetune ones, whole sequences, S·L of them at most."""
    found = recording(o)[o.finetune:]
    return found[: (len(found) // o.length) * o.length][: o.sequences * o.length]


def tune_frames(o: DetectorOptions) -> list[Path]:
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
        s.frames[folder] = load_frames(sorted((raw / folder).glob("frame_*.png")), o.grey)
    for folder, paths in (("real", real_frames(o)), ("tune", tune_frames(o))):
        if paths:
            s.frames[folder] = load_frames(paths, True, scale)
    return s


def targets(scene, draw) -> tuple[float, float, np.ndarray]:
    """(APPD %, bend %, the dense field: FIELD_COLUMNS grid × (moved x, y, rest x, y) in %) of one draw."""
    from appdgen.geometry.bend import warp_field
    from appdgen.sampling.sampler import target_px

    ref, ref_crop = scene.reference, scene.sampler().reference_rect.crop
    bend = target_px(scene.sampler(), draw, "bend")
    f = warp_field(ref, ref_crop, draw.calib, draw.rect.crop, FIELD_COLUMNS)
    dense = np.concatenate([f.moved, f.rest], axis=1).ravel()
    return px_to_pct(draw.appd_px, ref), px_to_pct(bend, ref), px_to_pct(dense, ref)


def make_pairs(scene, frames: np.ndarray, draws: list[tuple[int, int]], frame_ids: list[int]) -> dict:
    """Images (uint8 N×3×H×W) and targets of pairs: draw (seed, index) j on frame frame_ids[j]."""
    sampler = scene.sampler()
    images, appd, bend, dense = [], [], [], []
    for (seed, index), frame in zip(draws, frame_ids):
        draw = sampler.draw(seed, index)
        images.append(scene.render(frames[frame], draw).transpose(2, 0, 1))
        a, b, d = targets(scene, draw)
        appd.append(a)
        bend.append(b)
        dense.append(d)
    return {"image": np.stack(images), "appd": np.array(appd), "bend": np.array(bend), "field": np.stack(dense)}


def train_pairs(s: Stream, seed: int, first: int, count: int) -> dict:
    """fit --online's pairs first … first + count − 1 of a run with this seed, on the stream's training frames."""
    from train.online.pairs import frame_of

    n = len(s.frames["train"])
    ids = range(first, first + count)
    return make_pairs(s.scene, s.frames["train"], [(seed, i) for i in ids], [frame_of(seed, i, n) for i in ids])


def sequence_pairs(scene, frames: np.ndarray, seed: int, sequences: int, length: int) -> dict:
    """make_pairs of `sequences` sequences: sequence k = frames k·length … k·length + length − 1, all under draw
    (seed, k) (one miscalibration, as a robot's camera keeps it); as many as the frames allow, at most
    `sequences`."""
    count = min(sequences, len(frames) // length)
    draws = [(seed, k) for k in range(count) for _ in range(length)]
    return make_pairs(scene, frames, draws, list(range(count * length)))


def axis_pairs(s: Stream, axis: str, o: DetectorOptions) -> dict:
    """An axis's test pairs: sequence_pairs of its folder under AXIS_SEEDS[axis]."""
    folder = {"views": "train", "viewpoint": "viewpoint", "unseen": "unseen", "real": "real"}[axis]
    return sequence_pairs(s.scene, s.frames[folder], AXIS_SEEDS[axis], o.sequences, o.length)


def axes(o: DetectorOptions) -> list[str]:
    """The axes this run reports (real only with real frames)."""
    return ["views", "viewpoint", "unseen"] + (["real"] if real_frames(o) else [])


# --- networks -------------------------------------------------------------------------------------------


class Network:
    """One network arm: model, optimiser, target standardisation and the output line fitted after training."""

    def __init__(self, arm: Arm, first: dict, o: DetectorOptions, device) -> None:
        import torch

        from train.data import PixelStats
        from train.model import ModelConfig
        from train.nets import build

        self.arm, self.device = arm, device
        stats = PixelStats()
        stats.add(first["image"])
        mean, std, _ = stats.result()
        y = first[arm.target].reshape(len(first["image"]), -1)
        self.mean, self.std = y.mean(0), np.maximum(y.std(0), 1e-3)
        torch.manual_seed(o.seed)
        _, _, h, w = first["image"].shape
        cfg = ModelConfig(w, h, mean=tuple(mean), std=tuple(std), arch=arm.model,
                          outputs=y.shape[1] if arm.target == "field" else 1)
        self.net = build(cfg).to(device).to(memory_format=torch.channels_last).train()
        self.opt = torch.optim.Adam(self.net.parameters(), lr=o.lr)
        self.line = {t: (0.0, 1.0) for t in ("appd", "bend")}  # read-off → prediction: intercept, slope
        self.label_mean = {t: float(first[t].mean()) for t in ("appd", "bend")}

    def step(self, batch: dict, dtype) -> float:
        """One Adam step on the standardised target (train.loop's train_step, with its shape check)."""
        import torch

        from train.loop import train_step

        y = (batch[self.arm.target].reshape(len(batch["image"]), -1) - self.mean) / self.std
        label = torch.from_numpy(y.astype(np.float32))
        label = label if self.arm.target == "field" else label[:, 0]
        return float(train_step(self.net, self.opt, {"image": torch.from_numpy(batch["image"]), "label": label},
                                self.device, dtype))

    def read_off(self, images: np.ndarray, dtype, batch: int = 32) -> dict[str, np.ndarray]:
        """Raw read-offs per target: the scalar output, or the field's mean moved and rest lengths."""
        import torch

        from train import runtime
        from train.loop import to_input

        self.net.eval()
        out = []
        with torch.no_grad():
            for i in range(0, len(images), batch):
                x = to_input({"image": torch.from_numpy(images[i:i + batch])}, self.device)
                with runtime.autocast(self.device, dtype):
                    out.append(self.net(x).float().cpu().numpy().reshape(len(x), -1))
        self.net.train()
        y = np.concatenate(out) * self.std + self.mean
        if self.arm.target != "field":
            return {self.arm.target: y[:, 0]}
        points = y.reshape(len(y), -1, 4)
        return {"appd": np.hypot(points[..., 0], points[..., 1]).mean(1),
                "bend": np.hypot(points[..., 2], points[..., 3]).mean(1)}

    def fit_line(self, pairs: dict, dtype) -> None:
        """Least-squares line from read-off to target on fresh training pairs (a dense read-off is biased low)."""
        for t, r in self.read_off(pairs["image"], dtype).items():
            slope, intercept = np.polyfit(r, pairs[t], 1) if np.std(r) > 0 else (0.0, float(pairs[t].mean()))
            self.line[t] = (float(intercept), float(slope))

    def predict(self, images: np.ndarray, dtype) -> dict[str, list[float]]:
        """Predictions per target (% of diagonal) after the fitted line."""
        return {t: (self.line[t][0] + self.line[t][1] * r).tolist() for t, r in self.read_off(images, dtype).items()}


def floor_arms(arms: list[Arm], s: Stream, o: DetectorOptions, tests: dict[str, dict]) -> dict:
    """The plumb-line floor's predictions per axis and target (ridge fit on the first training pairs) and, with
    --finetune, the same fit with pairs of the first real frames added (arm plumbline+realN); {} when
    train.plumbline is missing."""
    try:
        from train.plumbline import PlumbLine, feature_matrix
    except ImportError:
        print("detector: train.plumbline not found; the floor arms are skipped", file=sys.stderr)
        return {}

    def features(pairs: dict) -> np.ndarray:
        """Line features of every pair's image (computed once, shared by both targets and every fit)."""
        return feature_matrix(pairs["image"].transpose(0, 2, 3, 1))

    start = time.process_time()
    pairs = train_pairs(s, o.seed, 0, o.floor_images)
    fits = [("plumbline", features(pairs), pairs)]
    if "tune" in s.frames:
        n = len(s.frames["tune"])
        tune = make_pairs(s.scene, s.frames["tune"], [(TUNE_SEED, i) for i in range(o.floor_images)],
                          [i % n for i in range(o.floor_images)])
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
    """Train every arm of one stream on the same pairs, fit their output lines, predict every axis."""
    import torch

    from train import runtime

    device = runtime.pick_device(o.device)
    dtype = runtime.autocast_dtype(device, "auto")
    arms = [a for a in ARMS if a.stream == stream and a.name in o.arms]
    s = open_stream(o, stream)
    nets = [Network(a, train_pairs(s, o.seed, 0, o.stats), o, device) for a in arms if a.model != "plumbline"]
    start, data_s, losses = time.process_time(), 0.0, {n.arm.name: [] for n in nets}
    for j in range(math.ceil(o.images / o.batch) if nets else 0):
        t0 = time.process_time()
        batch = train_pairs(s, o.seed, j * o.batch, min(o.batch, o.images - j * o.batch))
        data_s += time.process_time() - t0
        for n in nets:
            losses[n.arm.name].append(n.step(batch, dtype))
        if (j + 1) % 50 == 0:
            print(f"detector {stream}: {(j + 1) * o.batch} images, {time.process_time() - start:.0f} CPU s, loss "
                  + ", ".join(f"{k} {np.mean(v[-50:]):.3f}" for k, v in losses.items()), file=sys.stderr, flush=True)
    train_s = time.process_time() - start
    recal = train_pairs(s, RECAL_SEED, 0, o.recal)
    tests = {axis: axis_pairs(s, axis, o) for axis in axes(o)}
    result = {"stream": stream, "size": list(s.scene.size), "threads": torch.get_num_threads(),
              "train_cpu_s": train_s, "data_cpu_s": data_s, "images": o.images, "arms": {},
              "truth": {axis: {t: tests[axis][t].tolist() for t in ("appd", "bend")} for axis in tests}}
    for n in nets:
        n.fit_line(recal, dtype)
        # the weights, so that a later change of the scoring re-scores without retraining
        torch.save(n.net.state_dict(), Path(o.out) / f"{stream}-{n.arm.name.replace('/', '-')}.pt")
        w = max(1, len(losses[n.arm.name]) // 10)
        result["arms"][n.arm.name] = {
            "label_mean": n.label_mean[n.arm.target] if n.arm.target != "field" else n.label_mean,
            "line": n.line, "first_loss": float(np.mean(losses[n.arm.name][:w])),
            "last_loss": float(np.mean(losses[n.arm.name][-w:])),
            "predictions": {axis: n.predict(t["image"], dtype) for axis, t in tests.items()}}
    result["arms"].update(floor_arms([a for a in arms if a.model == "plumbline"], s, o, tests))
    return result


# --- metrics --------------------------------------------------------------------------------------------


def auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of `score` for the positives (Mann-Whitney, ties count half); nan if one class."""
    pos, neg = score[positive], score[~positive]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    greater = (pos[:, None] > neg[None, :]).mean()
    ties = (pos[:, None] == neg[None, :]).mean()
    return float(greater + 0.5 * ties)


def bootstrap_se(pred: np.ndarray, truth: np.ndarray, mean: float, length: int, rounds: int = 500) -> float:
    """Standard error of MAE / mean-predictor MAE when the sequences (the axis's miscalibrations) are resampled:
    how much the ratio owes to which few miscalibrations the axis drew."""
    err = np.abs(pred - truth).reshape(-1, length).mean(1)
    base = np.abs(mean - truth).reshape(-1, length).mean(1)
    pick = np.random.default_rng(0).integers(len(err), size=(rounds, len(err)))
    return float(np.std(err[pick].sum(1) / np.maximum(base[pick].sum(1), 1e-12)))


def metrics(pred: np.ndarray, truth: np.ndarray, appd: np.ndarray, mean: float, length: int) -> dict:
    """Per image: MAE / mean-predictor MAE, Spearman ρ, AUC of APPD > THRESHOLD; per sequence (`length`
    consecutive images, one miscalibration): the mean and the median prediction's MAE / the mean predictor's."""
    base = np.abs(mean - truth).mean()
    seq_pred = pred.reshape(-1, length)
    seq_truth = truth.reshape(-1, length)[:, 0]
    seq_base = np.abs(mean - seq_truth).mean()
    return {"ratio": float(np.abs(pred - truth).mean() / base), "ratio_se": bootstrap_se(pred, truth, mean, length),
            "mae": float(np.abs(pred - truth).mean()),
            "mean_mae": float(base), "rho": spearman(pred, truth), "auc": auc(pred, appd > THRESHOLD),
            "seq_mean": float(np.abs(seq_pred.mean(1) - seq_truth).mean() / seq_base),
            "seq_median": float(np.abs(np.median(seq_pred, 1) - seq_truth).mean() / seq_base),
            "n": int(len(pred)), "sequences": int(len(seq_truth))}


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
                                **metrics(np.array(pred), np.array(truth[t]), np.array(truth["appd"]), mean,
                                          o.length)})
    return out


def table(found: list[dict]) -> str:
    """The rows as a markdown table."""
    lines = ["| arm | target | size | axis | MAE / mean (± SE over sequences) | ρ | AUC @0.5 % | seq mean / mean | "
             "seq median / mean |",
             "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in found:
        lines.append(f"| {r['arm']} | {r['target']} | {r['size']} | {r['axis']} | {r['ratio']:.2f} ± {r['ratio_se']:.2f} | "
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
        procs = [subprocess.Popen([sys.executable, "-m", "train.detector", str(out / "options.json"), s,
                                   str(cores[i % len(cores)])]) for i, s in enumerate(streams)]
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


if __name__ == "__main__":
    child(sys.argv[1], sys.argv[2], int(sys.argv[3]))
