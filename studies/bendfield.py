"""The bend-field estimator (appdgen.detect, issue 32 items 5 and 6) as an arm of the detector comparison: the
comparison's axes, draws, labels and metrics (studies.detector, train.scoring), read from straight edges.

A pair of the comparison is a raw frame of the true camera (the reference) rectified with a sampler draw: the draw
is the robot's belief. So this arm reads sequence k of an axis with the Detector of draw k's calibration, which
rectifies the raw frames itself: each frame alone (per frame; the sequence's mean and median of those, as the other
arms) and the sequence's frames pooled in one solve (per sequence), against the draw's labels (train.scoring.LABELS:
APPD(reference, draw) and its bend, % of the raw diagonal, as the Detector's appd_pct and bend_pct are defined).
An abstention predicts the mean predictor's value (it says nothing) and is counted. The mean predictor is the mean
label of the prior's draws (seed, 0 … stats − 1), as the floor's is the mean of its training pairs' labels.

Axes: `views`, `viewpoint`, `unseen` (the comparison's synthetic streets, KITTI 02 at 1392×512, draws SEQUENCE_SEED),
`real` (EuRoC camera 1: a baseline from its first --baseline frames under the file's calibration, the sequences
from the frames after them, draws AXIS_SEEDS["real"]; also read without the baseline), and the unseen axis through
other lenses (LENSES: a Kannala–Brandt fisheye, an EUCM camera). The sequential test, on the streaming axes: a robot
reads the pooled window of its last --window frames at every frame; for every belief with APPD > THRESHOLD, the
frames until the verdict is "miscalibrated" (within --horizon frames), and under the true calibration the flagged
windows per 1,000 and the flagged disjoint sequences.

    python -m studies.bendfield [--tiny] [--sequences 32] [--lens-sequences 16] [--out runs/bendfield]

Models are cached under OUT/cache (not the user's cache). Prints the tables and a JSON line (command, CPU and wall
seconds, load); writes OUT/summary.json (rows and streams) and OUT/readings.json (every reading).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Iterator
from contextlib import nullcontext
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from appdgen.analysis.studies import spearman
from appdgen.detect import Baseline, Detector, Evidence, Reading
from appdgen.sources.frames import RawImage
from studies.detector import ARMS, AXIS_SEEDS, INTERP, TEST_SYNTH, DetectorOptions, listed, reference, synth_all
from studies.detector import table as comparison_table
from train.scoring import LABELS, MEAN_DRAWS, SEQUENCE_SEED, THRESHOLD, auc, prior_draws, sequence_metrics

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
#: Other lenses (issue 32 item 6): file, camera, --max-fov (the fisheye's valid region is unbounded without one).
LENSES = {"kb4": (SHARED / "formats" / "basalt_t265_kb4_calib.json", "cam0", 120.0),
          "eucm": (SHARED / "formats" / "basalt_euroc_eucm_calib.json", "cam0", None)}
TARGETS = ("appd", "bend")
AXES = ("views", "viewpoint", "unseen", "real")
MISCALIBRATED = "miscalibrated"


@dataclass(frozen=True)
class BendOptions:
    """Sizes of the study: the comparison's (frames, sequences, length, offset, seed) and the estimator's own."""

    out: str = "runs/bendfield"
    streets: str = ""  # the comparison's streets made elsewhere (train/, viewpoint/, unseen/); "": OUT/raw, made here
    frames: int = 300  # training streets: the views axis
    sequences: int = 32  # per KITTI axis (the views axis has frames // length of them at most)
    lens_sequences: int = 16  # per other lens
    length: int = 10
    offset: float = 0.3  # metres: the viewpoint axis
    scale: float = 1.0  # synthetic streets' scale (1: the comparison's full stream)
    stats: int = MEAN_DRAWS  # draws whose mean label is the mean predictor
    real: str = str(SHARED / "real" / "euroc_micro_cam1")  # data/ and sensor.yaml; "" for no real axis
    baseline: int = 30  # first real frames: the baseline under the file's calibration
    window: int = 10  # sequential test: frames pooled at every frame
    horizon: int = 20  # sequential test: frames streamed under each miscalibrated belief
    real_streams: int = 32  # sequential test on the real axis: draws streamed (its frames hold 6 sequences)
    axes: tuple[str, ...] = AXES
    lenses: tuple[str, ...] = tuple(LENSES)
    sequential: bool = True  # run the sequential test
    library: int = 0  # library draws of each belief's model (0: the Detector's default for its lens and size)
    cache: str = ""  # model cache (default OUT/cache)
    seed: int = 0
    jobs: int = 1  # processes: synthesis, and the beliefs read side by side


TINY = dict(frames=6, sequences=2, lens_sequences=2, length=3, scale=0.25, stats=16, baseline=4, window=3,
            horizon=4, real_streams=3, library=40)


# --- scenes and frames ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Scene:
    """One axis's camera and frames: the recipe (reference, sampling), its raw frames, the draw seed, max_fov."""

    name: str
    recipe: object  # train.online.recipe.PairRecipe
    images: list[RawImage]
    seed: int
    max_fov: float | None = None
    sequences: int = 0  # at most: as many as the frames hold
    streams: int = 0  # the sequential test streams the beliefs above THRESHOLD among draws 0 … streams − 1
    baseline_images: tuple[RawImage, ...] = ()


def recipe_of(calib, camera: str, max_fov: float | None = None):
    """The comparison's pair recipe of a camera at its raw size (default ranges and APPD range, bicubic)."""
    from appdgen.sampling.options import DEFAULT_ZERO_FRACTION, SamplingOptions
    from appdgen.sampling.sampler import DEFAULT_APPD_MAX
    from train.online.recipe import PairRecipe

    sampling = SamplingOptions.parse(calib, None, DEFAULT_APPD_MAX, DEFAULT_ZERO_FRACTION, max_fov, INTERP)
    return PairRecipe(calib, camera, calib.size, sampling)


def comparison(o: BendOptions) -> DetectorOptions:
    """The comparison's options for the same synthetic streets (its full stream, or its low one at --scale)."""
    stream = "full" if o.scale == 1.0 else "low"
    return DetectorOptions(out=o.out, frames=o.frames, sequences=o.sequences, length=o.length, offset=o.offset,
                           low_scale=o.scale, seed=o.seed, jobs=o.jobs,
                           arms=tuple(a.name for a in ARMS if a.stream == stream)[:1])


def street_scenes(o: BendOptions) -> list[Scene]:
    """The synthetic KITTI axes of o.axes, their streets synthesised once (studies.detector.synth_all)."""
    from appdgen.synth import scale_calibration

    wanted = [a for a in o.axes if a in ("views", "viewpoint", "unseen")]
    if not wanted:
        return []
    d = comparison(o)
    if not o.streets:
        synth_all(d)
    recipe = recipe_of(scale_calibration(reference(d), o.scale), "02")
    raw = Path(o.streets or Path(o.out) / "raw" / ("full" if o.scale == 1.0 else "low"))
    folder = {"views": "train", "viewpoint": "viewpoint", "unseen": "unseen"}
    return [Scene(a, recipe, listed(raw / folder[a]), AXIS_SEEDS[a], sequences=o.sequences,
                  streams=o.sequences if a == "unseen" and o.sequential else 0) for a in wanted]


def real_scene(o: BendOptions) -> list[Scene]:
    """The real axis: the recording's first o.baseline frames for the baseline, the rest for the sequences."""
    from appdgen.calib.formats import load

    if "real" not in o.axes or not o.real or not (Path(o.real) / "data").is_dir():
        return []
    images = listed(Path(o.real) / "data")
    recipe = recipe_of(load(str(Path(o.real) / "sensor.yaml")), "cam1")
    return [Scene("real", recipe, images[o.baseline:], AXIS_SEEDS["real"], sequences=o.sequences,
                  streams=o.real_streams if o.sequential else 0, baseline_images=tuple(images[:o.baseline]))]


def lens_scenes(o: BendOptions) -> list[Scene]:
    """The unseen axis through each of o.lenses: o.lens_sequences · length unseen streets synthesised once."""
    from appdgen.calib.formats import load
    from appdgen.synth import CAR, scale_calibration, synthesize

    scenes = []
    for name in o.lenses:
        path, camera, max_fov = LENSES[name]
        if not path.exists():
            continue
        calib = scale_calibration(load(str(path), camera), o.scale)
        where, count = Path(o.out) / "raw" / f"lens-{name}" / "unseen", o.lens_sequences * o.length
        if len(listed(where)) != count:
            synthesize(calib, count, where, TEST_SYNTH + o.seed, 1.0, jobs=o.jobs, mount=CAR)
        scenes.append(Scene(f"unseen-{name}", recipe_of(calib, camera, max_fov), listed(where), SEQUENCE_SEED,
                            max_fov, o.lens_sequences, o.lens_sequences if o.sequential else 0))
    return scenes


def grey_frames(images: list[RawImage]) -> Iterator[np.ndarray]:
    """The frames' 8-bit grey pixels, in order, read through appdgen.sources."""
    from appdgen.sources.inputs import iter_images

    return iter_images(images, 1)


# --- readings -------------------------------------------------------------------------------------------


class Readers:
    """The Detector of each belief (its model from OUT/cache) and the evidence of each (belief, frame) read once."""

    def __init__(self, o: BendOptions) -> None:
        self.cache = Path(o.cache or Path(o.out) / "cache")
        self.library = o.library
        self.detectors: dict[object, Detector] = {}
        self.model_s: list[float] = []
        self.evidence_s: list[float] = []

    def detector(self, belief, max_fov: float | None) -> Detector:
        """The belief's Detector (the last few kept)."""
        key = (belief, max_fov)
        if key not in self.detectors:
            extra = {"library_draws": self.library} if self.library else {}
            det = Detector(belief, max_fov, cache_dir=self.cache, **extra)
            self.model_s.append(det.seconds_to_model)
            self.detectors = {**dict(list(self.detectors.items())[-3:]), key: det}
        return self.detectors[key]

    def evidence(self, det: Detector, images: list[RawImage]) -> list[Evidence]:
        """Each frame's line evidence under the detector's belief."""
        out = []
        for raw, image in zip(grey_frames(images), images, strict=False):
            out.append(det.evidence(raw, image.name))
            self.evidence_s.append(out[-1].seconds)
        return out


def reading(r: Reading) -> dict:
    """The fields the tables use: appd and bend (None: abstained), p_above, verdict, segments."""
    return {"appd": r.appd_pct, "appd_sd": r.appd_sd_pct, "bend": r.bend_pct, "p_above": r.p_above,
            "verdict": r.verdict, "segments": r.segments}


def label_mean(scene: Scene, o: BendOptions) -> dict[str, float]:
    """The mean predictor per target: the mean label of the prior's draws (o.seed, 0 … o.stats − 1)."""
    sampler = scene.recipe.sampler()
    draws = prior_draws(sampler, o.seed, o.stats)
    return {t: float(np.mean([LABELS[t](scene.recipe, d) for d in draws])) for t in TARGETS}


def windows(det: Detector, evidence: list[Evidence], baseline: Baseline | None, window: int) -> list[dict]:
    """What a robot reads at every frame of a stream: the pooled window of its last `window` frames."""
    return [reading(det.read(evidence[max(0, t + 1 - window):t + 1], baseline)) for t in range(len(evidence))]


def frames_to_flag(found: list[dict]) -> int | None:
    """Frames streamed until the first "miscalibrated" verdict (1-based); None: never within the stream."""
    return next((t + 1 for t, r in enumerate(found) if r["verdict"] == MISCALIBRATED), None)


def stream_images(images: list[RawImage], first: int, count: int) -> list[RawImage]:
    """`count` frames of the axis from `first` on, wrapping around its end."""
    return [images[(first + j) % len(images)] for j in range(count)]


def read_belief(scene: Scene, o: BendOptions, baseline: Baseline | None, k: int) -> dict | None:
    """Draw k of a scene as the belief: its sequence read per frame and pooled (with and, on the real axis,
    without the baseline) while k < the scene's sequences, and its stream when it is above THRESHOLD; None when
    neither. Also the seconds its model and evidence took, and a line for the log."""
    L, readers = o.length, Readers(o)
    count = min(scene.sequences, len(scene.images) // L)
    draw = scene.recipe.sampler().draw(scene.seed, k)
    labels = {t: float(LABELS[t](scene.recipe, draw)) for t in TARGETS}
    streamed = k < scene.streams and labels["appd"] > THRESHOLD
    if k >= count and not streamed:
        return None
    det = readers.detector(draw.calib, scene.max_fov)
    evidence = readers.evidence(det, stream_images(scene.images, k * L, L if k < count else 0))
    variants = {"": baseline} if baseline is None else {"": baseline, " (no baseline)": None}
    out = {"sequences": {v: {**labels, "frames": [reading(det.read([e], b)) for e in evidence],
                             "pooled": reading(det.read(evidence, b))} for v, b in variants.items()}
           if k < count else {}, "stream": None}
    if streamed:
        evidence += readers.evidence(det, stream_images(scene.images, k * L + len(evidence),
                                                        max(0, o.horizon - len(evidence))))
        found = windows(det, evidence[:o.horizon], baseline, o.window)
        out["stream"] = {"k": k, "appd": labels["appd"], "frames_to_flag": frames_to_flag(found)}
    said = f", pooled {out['sequences']['']['pooled']['appd']}" if k < count else ", streamed"
    return {**out, "model_s": readers.model_s, "evidence_s": readers.evidence_s,
            "log": f"{scene.name} belief {k + 1}: APPD {labels['appd']:.3f} %{said}"}


def read_scene(scene: Scene, o: BendOptions, readers: Readers, log) -> dict:
    """Every belief of a scene (read_belief; o.jobs processes when > 1) and the true calibration's stream."""
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial

    truth, baseline = scene.recipe.reference, None
    if scene.baseline_images:
        ref = readers.detector(truth, scene.max_fov)
        baseline = ref.save_baseline(readers.evidence(ref, list(scene.baseline_images)),
                                     f"{scene.name} frames 0-{len(scene.baseline_images) - 1}")
    task, beliefs = partial(read_belief, scene, o, baseline), range(max(scene.sequences, scene.streams))
    result = {"sequences": {}, "streams": []}
    with ProcessPoolExecutor(o.jobs) if o.jobs > 1 else nullcontext() as pool:
        for found in (pool.map(task, beliefs) if pool else map(task, beliefs)):
            if found is None:
                continue
            for variant, seq in found["sequences"].items():
                result["sequences"].setdefault(variant, []).append(seq)
            result["streams"] += [found["stream"]] if found["stream"] else []
            readers.model_s += found["model_s"]
            readers.evidence_s += found["evidence_s"]
            log(found["log"])
    if scene.streams:
        det = readers.detector(truth, scene.max_fov)
        evidence = readers.evidence(det, scene.images)
        result["truth"] = windows(det, evidence, baseline, o.window)
        result["truth_frames"] = [reading(det.read([e], baseline)) for e in evidence]
    return result


# --- metrics and tables ---------------------------------------------------------------------------------


def predictions(seqs: list[dict], target: str, mean: float) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Per-frame and pooled predictions of a target (an abstention predicts `mean`) and the abstentions of each."""
    frames = [f[target] for s in seqs for f in s["frames"]]
    pooled = [s["pooled"][target] for s in seqs]
    fill = lambda v: np.array([mean if x is None else x for x in v], dtype=float)  # noqa: E731
    return fill(frames), fill(pooled), sum(x is None for x in frames), sum(x is None for x in pooled)


def arm_metrics(seqs: list[dict], target: str, mean: float, length: int) -> dict:
    """train.scoring.sequence_metrics of the per-frame readings, plus the pooled (one-solve) reading's MAE / the
    mean predictor's, Spearman ρ and AUC of APPD > THRESHOLD over the sequences, and the abstentions."""
    per_frame, pooled, abstained, pooled_abstained = predictions(seqs, target, mean)
    truth = np.array([s[target] for s in seqs])
    appd = np.array([s["appd"] for s in seqs])
    m = sequence_metrics(per_frame, np.repeat(truth, length), np.repeat(appd, length), mean, length)
    return {**m, "pooled": float(np.abs(pooled - truth).mean() / np.abs(mean - truth).mean()),
            "pooled_bias": float((pooled - truth).mean()), "bias": float((per_frame - np.repeat(truth, length)).mean()),
            "pooled_rho": spearman(pooled, truth), "pooled_auc": auc(pooled, appd > THRESHOLD),
            "abstained": abstained, "pooled_abstained": pooled_abstained, "label_mean": mean}


def stream_metrics(result: dict, o: BendOptions) -> dict:
    """The sequential test: frames until a belief above THRESHOLD is flagged, and the true calibration's flags."""
    delays = [s["frames_to_flag"] for s in result["streams"]]
    found = [d for d in delays if d is not None]
    out = {"miscalibrated": len(delays), "flagged": len(found),
           "median_frames": float(np.median(found)) if found else None, "horizon": o.horizon}
    if "truth" in result:
        full, ends = result["truth"][o.window - 1:], result["truth"][o.length - 1::o.length]
        flagged = lambda found: sum(r["verdict"] == MISCALIBRATED for r in found)  # noqa: E731
        out |= {"windows": len(full), "false_alarms_per_1000": 1000.0 * flagged(full) / max(1, len(full)),
                "sequences": len(ends), "sequences_flagged": flagged(ends),
                "truth_window_appd": mean_of(full, "appd"),
                "truth_frame_appd": mean_of(result["truth_frames"], "appd"),
                "truth_frame_bend": mean_of(result["truth_frames"], "bend")}
    return out


def mean_of(found: list[dict], key: str) -> float | None:
    """The mean of a reading field over the readings that gave one (the true calibration's: the bias)."""
    values = [r[key] for r in found if r[key] is not None]
    return float(np.mean(values)) if values else None


def rows(readings: dict, means: dict, sizes: dict, o: BendOptions) -> list[dict]:
    """One row per axis (and baseline variant) × target."""
    out = []
    for axis, result in readings.items():
        for variant, seqs in result["sequences"].items():
            for t in TARGETS:
                out.append({"arm": "bendfield" + variant, "target": t, "size": sizes[axis], "axis": axis,
                            **arm_metrics(seqs, t, means[axis][t], o.length)})
    return out


def table(found: list[dict]) -> str:
    """The rows as a markdown table: the comparison's columns (studies.detector.table), then the pooled reading's."""
    extra = [" pooled / mean | pooled ρ | pooled AUC | abstained (frames, seq.) |", "---:|---:|---:|---:|"]
    extra += [f" **{r['pooled']:.2f}** | {r['pooled_rho']:.2f} | {r['pooled_auc']:.2f} | {r['abstained']}/{r['n']}, "
              f"{r['pooled_abstained']}/{r['sequences']} |" for r in found]
    return "\n".join(a + b for a, b in zip(comparison_table(found).splitlines(), extra, strict=False))


def line(row: dict, length: int) -> str:
    """One row for a human: per frame and per sequence against the mean predictor."""
    return (f"{row['arm']}, {row['target']}, {row['axis']} ({row['size']}): MAE / the mean predictor's "
            f"{row['ratio']:.2f} per frame, "
            f"{row['pooled']:.2f} per sequence of {length} (one pooled solve; {row['sequences']} sequences)")


def stream_table(found: dict[str, dict]) -> str:
    """The sequential test as a markdown table."""
    lines = ["| axis | beliefs > 0.5 % flagged within the horizon | median frames to flag | true calibration: "
             "flagged windows per 1,000 | sequences flagged | true calibration reads APPD (frame / window) |",
             "|---|---:|---:|---:|---:|---:|"]
    pct = lambda v: "—" if v is None else f"{v:.2f} %"  # noqa: E731
    for axis, s in found.items():
        median = "—" if s["median_frames"] is None else f"{s['median_frames']:g}"
        truth = (f"{s['false_alarms_per_1000']:.0f} ({s['windows']} windows) | {s['sequences_flagged']} of "
                 f"{s['sequences']} | {pct(s['truth_frame_appd'])} / {pct(s['truth_window_appd'])}"
                 if "windows" in s else "— | — | —")
        lines.append(f"| {axis} | {s['flagged']} of {s['miscalibrated']} in {s['horizon']} | {median} | {truth} |")
    return "\n".join(lines)


# --- the run --------------------------------------------------------------------------------------------


def run(o: BendOptions, log=lambda line: print(line, file=sys.stderr, flush=True)) -> dict:
    """Synthesise (once), read every scene, score; OUT/summary.json and OUT/readings.json."""
    out = Path(o.out)
    out.mkdir(parents=True, exist_ok=True)
    start, cpu, version = time.perf_counter(), cpu_seconds(), detect_version()
    scenes = street_scenes(o) + real_scene(o) + lens_scenes(o)
    synth_s = time.perf_counter() - start
    readers, readings, means, sizes = Readers(o), {}, {}, {}
    for scene in scenes:
        means[scene.name] = label_mean(scene, o)
        sizes[scene.name] = "x".join(map(str, scene.recipe.reference.size))
        readings[scene.name] = read_scene(scene, o, readers, log)
    found = rows(readings, means, sizes, o)
    streams = {a: stream_metrics(r, o) for a, r in readings.items() if r["streams"] or "truth" in r}
    costs = {"options": asdict(o), "axes": list(readings), "detect": version, "synth_s": synth_s,
             "wall_s": time.perf_counter() - start,
             "cpu_s": cpu_seconds() - cpu, "models": len(readers.model_s),
             "model_s": float(np.sum(readers.model_s)), "evidence_frames": len(readers.evidence_s),
             "evidence_s": float(np.sum(readers.evidence_s))}
    merged(out / "readings.json", {"means": means, "readings": readings})
    summary = merged(out / "summary.json", {"rows": found, "streams": streams, "runs": [costs]})
    return {**summary, **costs}


def cpu_seconds() -> float:
    """CPU seconds of this process and its finished children (the --jobs workers)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def detect_version() -> dict:
    """Which estimator is measured: the repository's commit and a digest of appdgen/detect's sources now."""
    import hashlib
    import subprocess

    import appdgen.detect

    digest = hashlib.sha1()
    for path in sorted(Path(appdgen.detect.__file__).parent.glob("*.py")):
        digest.update(path.read_bytes())
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return {"commit": head.stdout.strip(), "sources_sha1": digest.hexdigest()[:12]}


def merged(path: Path, now: dict) -> dict:
    """`now` joined to what an earlier run of other axes stored at `path` (this run's axes replace theirs),
    written back: axes run one at a time join one table."""
    if path.exists():
        before = json.loads(path.read_text())
        axes = {r["axis"] for r in now.get("rows", [])} | set(now.get("readings", {}))
        for key, value in now.items():
            if key == "rows":
                order = [*AXES, *(f"unseen-{name}" for name in LENSES)]
                now[key] = sorted([r for r in before.get(key, []) if r["axis"] not in axes] + value,
                                  key=lambda r: (order.index(r["axis"]) if r["axis"] in order else len(order)))
            elif key == "runs":
                now[key] = before.get(key, []) + value
            else:
                now[key] = {**before.get(key, {}), **value}
    path.write_text(json.dumps(now, indent=1 if path.name == "summary.json" else None))
    return now


def options(argv: list[str] | None = None) -> tuple[BendOptions, bool]:
    """BendOptions from the command line (--tiny: TINY's sizes where not given), and whether --lines."""
    parser = argparse.ArgumentParser(prog="python -m studies.bendfield", description=__doc__.splitlines()[0])
    parser.add_argument("--tiny", action="store_true", help="2 sequences of 3 frames at 348x128: the chain only.")
    parser.add_argument("--lines", action="store_true", help="One line per axis instead of the tables.")
    for f in fields(BendOptions):
        flag = "--" + f.name.replace("_", "-")
        if f.name in ("axes", "lenses"):
            parser.add_argument(flag, help="comma-separated")
        elif f.type == "bool":
            parser.add_argument("--no-" + f.name, dest=f.name, action="store_const", const=False)
        else:
            parser.add_argument(flag, type={"int": int, "float": float}.get(f.type, str), default=None)
    args = parser.parse_args(argv)
    given = {f.name: getattr(args, f.name) for f in fields(BendOptions) if getattr(args, f.name) is not None}
    for name in ("axes", "lenses"):
        if name in given:
            given[name] = tuple(x for x in given[name].split(",") if x)
    o = BendOptions(**given)
    return (replace(o, **{k: v for k, v in TINY.items() if k not in given}) if args.tiny else o), args.lines


def main(argv: list[str] | None = None) -> dict:
    """Run the study and print its tables and a JSON line."""
    argv = sys.argv[1:] if argv is None else argv
    o, lines = options(argv)
    load_before = os.getloadavg()
    summary = run(o)
    if lines:
        print("\n".join(line(r, o.length) for r in summary["rows"]))
        return summary
    print(table(summary["rows"]))
    print()
    print(stream_table(summary["streams"]))
    print(json.dumps({"command": " ".join(["python", "-m", "studies.bendfield", *argv]),
                      "wall_s": round(summary["wall_s"]), "cpu_s": round(summary["cpu_s"]),
                      "synth_s": round(summary["synth_s"]), "models": summary["models"],
                      "model_s": round(summary["model_s"]), "evidence_frames": summary["evidence_frames"],
                      "evidence_s": round(summary["evidence_s"]), "load_before": load_before,
                      "load_after": os.getloadavg()}))
    return summary


if __name__ == "__main__":
    main()
