"""What `evaluate` reports, owned here for every scorer (evaluate --shards and --frames, the studies): the error
metrics per image and per APPD bin, the test pairs of sequences under one fixed-seed miscalibration each, their
per-sequence metrics, and the line a human reads. Labels and metrics are % of the raw image diagonal."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from appdgen.analysis.studies import spearman  # ties share their mean rank; nan when a side is constant
from appdgen.detect import DEFAULT_THRESHOLD_PCT
from appdgen.geometry.appd import px_to_pct
from appdgen.sampling.sampler import target_px

N_BINS = 10
#: Draw seed of the test sequences: sequence k of any test set is under draw (SEQUENCE_SEED, k), so that every
#: scorer (evaluate --frames, the detector comparison's synthetic axes) tests on the same miscalibrations.
SEQUENCE_SEED = 7003
#: % APPD: the detection threshold whose AUC the sequence metrics report (the detector's, owned by appdgen.detect).
THRESHOLD = DEFAULT_THRESHOLD_PCT
#: The detector studies' mean predictor is the mean label of the prior's draws (MEAN_SEED, 0 … MEAN_DRAWS − 1).
MEAN_SEED = 0
MEAN_DRAWS = 300
#: A label: its value of a draw under a recipe (train.online.recipe.PairRecipe), % of the raw diagonal.
Label = Callable[[object, object], object]


def prior_draws(sampler, seed: int = MEAN_SEED, count: int = MEAN_DRAWS) -> list:
    """The sampler's draws (seed, 0 … count − 1) whose mean label is the detector studies' mean predictor."""
    return [sampler.draw(seed, i) for i in range(count)]


def target_label(target: str) -> Label:
    """The Label of a target (appd, bend: sampling.sampler.target_px), % of the raw diagonal."""
    def label(recipe: object, draw: object) -> float:
        """The target's value of the draw, % of the recipe reference's raw diagonal."""
        return px_to_pct(target_px(recipe.sampler(), draw, target), recipe.reference)
    return label


#: A pair's labels: name → Label.
LABELS: dict[str, Label] = {t: target_label(t) for t in ("appd", "bend")}


# --- per image and per bin ---------------------------------------------------------------------------------


def bin_edges(appd_max: float, n_bins: int = N_BINS) -> np.ndarray:
    """n_bins + 1 equal-width edges over [0, appd_max] (APPD %)."""
    return np.linspace(0.0, appd_max, n_bins + 1)


def bin_index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin of each value; values past the last edge go to the last bin, below 0 to the first."""
    return np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)


def per_bin(y_true: np.ndarray, y_pred: np.ndarray, edges: np.ndarray) -> list[dict]:
    """MAE and mean prediction per true-APPD bin (null where a bin is empty)."""
    idx = bin_index(y_true, edges)
    rows = []
    for b in range(len(edges) - 1):
        m = idx == b
        n = int(m.sum())
        rows.append({
            "lo": float(edges[b]), "hi": float(edges[b + 1]), "n": n,
            "mae": float(np.abs(y_pred[m] - y_true[m]).mean()) if n else None,
            "pred_mean": float(y_pred[m].mean()) if n else None,
        })
    return rows


def classification(y_true: np.ndarray, y_pred: np.ndarray, threshold: float) -> dict:
    """Precision, recall and F1 of 'APPD > threshold' (null where a ratio is 0/0)."""
    t, p = y_true > threshold, y_pred > threshold
    tp, fp, fn = int((t & p).sum()), int((~t & p).sum()), int((t & ~p).sum())
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = 2 * precision * recall / (precision + recall) if precision and recall else (0.0 if tp + fp + fn else None)
    return {"threshold": threshold, "precision": precision, "recall": recall, "f1": f1,
            "tp": tp, "fp": fp, "fn": fn, "tn": int((~t & ~p).sum())}


def metrics(y_true: np.ndarray, y_pred: np.ndarray, label_mean: float, appd_max: float, threshold: float) -> dict:
    """MAE, RMSE, the mean predictor's MAE, per-bin MAE and threshold classification (APPD %)."""
    err = y_pred - y_true
    mae = float(np.abs(err).mean())
    base = float(np.abs(label_mean - y_true).mean())
    return {
        "n": int(len(y_true)), "mae": mae, "rmse": float(np.sqrt((err**2).mean())),
        "median_abs_error": float(np.median(np.abs(err))),
        "mean_predictor_mae": base, "mae_vs_mean_predictor": mae / base if base > 0 else None,
        "train_label_mean": label_mean, "appd_max": appd_max,
        "bins": per_bin(y_true, y_pred, bin_edges(appd_max)),
        "classification": classification(y_true, y_pred, threshold),
    }


# --- sequences --------------------------------------------------------------------------------------------


def make_pairs(recipe, frames: np.ndarray, draws: list[tuple[int, int]], frame_ids: list[int],
               labels: dict[str, Label] = LABELS) -> dict:
    """Images (uint8 N×3×H×W) and each of `labels` (arrays over the pairs) of pairs: draw (seed, index) j of the
    recipe's sampler on frame frame_ids[j], rendered as the cpu renderer (and `appdgen build`) does."""
    sampler = recipe.sampler()
    images, values = [], {name: [] for name in labels}
    for (seed, index), frame in zip(draws, frame_ids, strict=True):
        draw = sampler.draw(seed, index)
        images.append(recipe.render(frames[frame], draw).transpose(2, 0, 1))
        for name, label in labels.items():
            values[name].append(label(recipe, draw))
    return {"image": np.stack(images), **{name: np.array(v) for name, v in values.items()}}


def sequence_pairs(recipe, frames: np.ndarray, seed: int, sequences: int, length: int,
                   labels: dict[str, Label] = LABELS) -> dict:
    """make_pairs of `sequences` sequences: sequence k = frames k·length … k·length + length − 1, all under draw
    (seed, k) (one miscalibration, as a robot's camera keeps it); as many as the frames allow, at most
    `sequences`."""
    count = min(sequences, len(frames) // length)
    draws = [(seed, k) for k in range(count) for _ in range(length)]
    return make_pairs(recipe, frames, draws, list(range(count * length)), labels)


def auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of `score` for the positives (Mann-Whitney, ties count half); nan if one class."""
    pos, neg = score[positive], score[~positive]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    greater = (pos[:, None] > neg[None, :]).mean()
    ties = (pos[:, None] == neg[None, :]).mean()
    return float(greater + 0.5 * ties)


def bootstrap_se(pred: np.ndarray, truth: np.ndarray, mean: float, length: int, rounds: int = 500) -> float:
    """Standard error of MAE / mean-predictor MAE when the sequences (the test's miscalibrations) are resampled:
    how much the ratio owes to which few miscalibrations the test drew."""
    err = np.abs(pred - truth).reshape(-1, length).mean(1)
    base = np.abs(mean - truth).reshape(-1, length).mean(1)
    pick = np.random.default_rng(0).integers(len(err), size=(rounds, len(err)))
    return float(np.std(err[pick].sum(1) / np.maximum(base[pick].sum(1), 1e-12)))


def sequence_metrics(pred: np.ndarray, truth: np.ndarray, appd: np.ndarray, mean: float, length: int) -> dict:
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


def summary_line(result: dict) -> str:
    """'split: MAE … vs mean predictor … (ratio …)' in % of the diagonal, for a human reading an evaluation (the
    callers put their name in front: evaluate, paper-scale)."""
    ratio = result["mae_vs_mean_predictor"]
    target = "" if result["target"] == "appd" else f" ({result['label']})"
    line = (f"{result['split']}{target} MAE {result['mae']:.3f} % vs mean-predictor MAE "
            f"{result['mean_predictor_mae']:.3f} % (ratio {'n/a' if ratio is None else f'{ratio:.2f}'}) "
            f"on {result['n']} images")
    seq = result.get("sequences")
    if seq:  # evaluate --frames
        line += (f"; per sequence of {seq['length']} (one miscalibration, {seq['count']} sequences): mean "
                 f"prediction {seq['mean_vs_mean_predictor']:.2f}, median {seq['median_vs_mean_predictor']:.2f} "
                 f"× the mean predictor's MAE")
    return line
