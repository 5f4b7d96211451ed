"""`mvpd report`: the paper's model tables for one run, as Markdown and pictures.

For each model spec (`geometric`, `geometric+sp`: `+sp` = wrapped in FastSPAM self-prompting) it
predicts (`<out>/predictions/<spec>/`, a prediction folder: only videos without a valid marker run)
and evaluates (VSQ, the published protocol of the run's job); each model's per-video counts are kept
in `<out>/scores/<spec>.json` with a stamp of the predictions and protocol, so a report run again
re-scores only models whose predictions changed. Then it writes `<out>/report.md` with:
VSQ^k and VSQ per model; the same per camera height with the difference (the paper's sensor
placement finding); the zero-shot bucket (missing until the run has a split); each segmenter per
frame against itself with self-prompting; and pictures (`vsq_by_k.png`, `vsq_by_height.png`,
`strip.png`: RGB | ground truth | each model's masks for frames of one video).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from pipeline.config import config_hash
from pipeline.evaluate.predictions import RLE_FOLDER, read_rle_file
from pipeline.evaluate.vsq import AGGREGATE, ZERO_SHOT, Counts, VideoCounts, VsqProtocol, summarize
from pipeline.models.predict import NO_SPLIT, SELF_PROMPTING_SUFFIX, ModelConfig, build_model, predict_run, resolve_embodiment
from pipeline.store.names import atomic_write_text, replaced
from pipeline.store.run_folder import RunFolder
from pipeline.runtime.runner import Observer

KS_LABELS = ("1", "5", "10", "15")


class ReportError(RuntimeError):
    """A model whose predictions or scores are incomplete: no report is written from partial numbers."""


@dataclass
class ModelScores:
    """One model's per-video counts on the run (keys "<embodiment>/<video_name>")."""

    spec: str
    per_video: dict[str, VideoCounts]
    protocol: VsqProtocol

    def summary(self, keys: Sequence[str] | None = None) -> dict[str, dict[str, float | None]]:
        """VSQ^k and VSQ per bucket over `keys` (all videos when None)."""
        chosen = self.per_video if keys is None else {k: self.per_video[k] for k in keys if k in self.per_video}
        return summarize(chosen.values(), self.protocol.ks)


def video_height_m(key: str) -> float:
    """Camera height of a video from its name `<scene>.<trajectory>.<height_mm>`."""
    return int(key.rsplit(".", 1)[1]) / 1000.0


def _stamp(prediction_folder: Path, protocol: VsqProtocol) -> str:
    """Changes whenever a video's predictions are re-committed or the protocol changes."""
    markers = RunFolder(prediction_folder).markers("predict")
    return config_hash({"protocol": [list(protocol.ks), protocol.window, protocol.stride, protocol.min_area_fraction,
                                     protocol.subsample],
                        "units": sorted((m.unit, m.config_hash, m.finished_at) for m in markers.values())})


def _load_scores(path: Path, stamp: str, spec: str, protocol: VsqProtocol) -> ModelScores | None:
    if not path.is_file():
        return None
    data = json.loads(path.read_text(encoding="utf-8"))
    if data.get("stamp") != stamp:
        return None
    per_video = {}
    for key, buckets in data["per_video"].items():
        counts = VideoCounts(protocol.ks)
        for bucket, per_k in buckets.items():
            for k, values in per_k.items():
                counts.buckets[bucket][int(k)] = Counts(values["IOU"], values["TP"], values["FP"], values["FN"])
        per_video[key] = counts
    return ModelScores(spec, per_video, protocol)


def score_model(run: RunFolder, spec: str, out: Path, embodiment: str, videos: Sequence[str] | None,
                selection: str, address: str | None, observer: Observer) -> ModelScores:
    """Predict (what is missing) and evaluate (unless the stored scores are current) one model spec."""
    from pipeline.evaluate.api import evaluate_run

    config = ModelConfig.from_spec(spec)
    folder = out / "predictions" / spec
    report = predict_run(run, folder, config, embodiment, videos, selection,
                         address=address, on_start=observer.on_stage_start, on_unit=observer.on_unit)
    if observer.on_stage_end is not None:
        observer.on_stage_end(report)
    protocol = VsqProtocol.from_config(run.job().evaluate)
    stamp = _stamp(folder, protocol)
    cache = out / "scores" / f"{spec}.json"
    cached = _load_scores(cache, stamp, spec, protocol)
    if cached is not None:
        return cached
    if report.failed:  # a table over the videos that happened to work would mislead
        raise ReportError(f"{spec}: {len(report.failed)} videos failed to predict (e.g. {report.failed[0].unit}: "
                          f"{report.failed[0].message}); see `mvpd status {folder}`, fix, and report again")
    result = evaluate_run(run, folder, embodiment, on_start=observer.on_stage_start, on_unit=observer.on_unit,
                          split=None if selection == NO_SPLIT else selection)
    if result.failed:
        raise ReportError(f"{spec}: {len(result.failed)} videos failed to evaluate (e.g. {result.failed[0].unit}: "
                          f"{result.failed[0].message}); see `mvpd status {run.location}`")
    scores = ModelScores(spec, dict(result.per_video), protocol)
    atomic_write_text(cache, json.dumps({"stamp": stamp, "per_video": {k: v.as_dict() for k, v in sorted(scores.per_video.items())}}))
    return scores


def _default_split(run: RunFolder, embodiment: str) -> tuple[str, list[str] | None]:
    """As `mvpd evaluate`: the test split's accepted videos when the run has a split, else every video."""
    from pipeline.split.selection import accepted_videos

    accepted = accepted_videos(run, "test")
    if accepted is None:
        return NO_SPLIT, None
    return "test", sorted(name for owner, name in accepted if owner == embodiment)


def write_model_report(run: RunFolder, specs: Sequence[str], out: str | Path | None = None,
                       embodiment: str | None = None, videos: Sequence[str] | None = None, selection: str = NO_SPLIT,
                       address: str | None = None, observer: Observer | None = None) -> Path:
    """Predict, evaluate and write `report.md` + pictures for `specs` on one run; returns report.md's path.

    `videos` (with `selection`, the split's name) restricts the report to a split's videos; by default a run with
    a split reports its test split (as `mvpd evaluate` does), a run without one every video.
    """
    from pipeline.models.segmenter import ModelError

    if not specs:
        raise ModelError("--models is empty; give model specs such as geometric,geometric+sp")
    for spec in specs:  # every name and extra is checked before anything is written
        build_model(ModelConfig.from_spec(spec))
    chosen = resolve_embodiment(run, embodiment or run.job().embodiments[0].name)
    if videos is None and selection == NO_SPLIT:
        selection, videos = _default_split(run, chosen)
    target = Path(out) if out is not None else run.root / "report"
    target = target.expanduser().resolve()
    observer = observer or Observer()
    scores = [score_model(run, spec, target, chosen, videos, selection, address, observer) for spec in specs]
    pictures = [_plot_by_k(scores, target / "vsq_by_k.png"), _plot_by_height(scores, target / "vsq_by_height.png"),
                _picture_strip(run, chosen, specs, target, target / "strip.png")]
    path = target / "report.md"
    atomic_write_text(path, _markdown(run, chosen, scores, [p for p in pictures if p is not None], selection))
    return path


# ------------------------------------------------------------------------------------ tables


def _percent(value: float | None) -> str:
    # + 0.0 turns the -0.0 of a difference of equal sums added in another order into 0.00
    return "missing" if value is None else f"{round(100 * value, 2) + 0.0:.2f}"


def _row(label: str, values: dict[str, float | None]) -> str:
    return "| " + " | ".join([label, *[_percent(values.get(k)) for k in (*KS_LABELS, "VSQ")]]) + " |"


def _header(first: str) -> list[str]:
    return [f"| {first} | VSQ^1 | VSQ^5 | VSQ^10 | VSQ^15 | VSQ |", "|---|---:|---:|---:|---:|---:|"]


def _difference(a: dict[str, float | None], b: dict[str, float | None]) -> dict[str, float | None]:
    return {k: (a[k] - b[k]) if a.get(k) is not None and b.get(k) is not None else None  # type: ignore[operator]
            for k in (*KS_LABELS, "VSQ")}


def _heights(scores: list[ModelScores]) -> list[float]:
    return sorted({video_height_m(key) for s in scores for key in s.per_video}, reverse=True)


def _markdown(run: RunFolder, embodiment: str, scores: list[ModelScores], pictures: list[Path], selection: str) -> str:
    videos = sorted({key for s in scores for key in s.per_video})
    lines = [f"# Model report: {run.root.name}", "",
             f"Run `{run.root}`, embodiment `{embodiment}`, {len(videos)} videos "
             f"({'split ' + selection if selection != NO_SPLIT else 'every video: the run has no split'}). VSQ in percent, the published "
             "protocol of the run's job (`evaluate` section). `+sp` = FastSPAM self-prompting around the segmenter. "
             "\"missing\" = nothing was counted (a video needs more than `window` frames to hold a window).", "",
             "## VSQ per model", "", *_header("model")]
    lines += [_row(s.spec, s.summary()[AGGREGATE]) for s in scores]
    lines += ["", "## Per camera height", "", *_header("model @ height")]
    heights = _heights(scores)
    for s in scores:
        by_height = {h: s.summary([k for k in s.per_video if video_height_m(k) == h])[AGGREGATE] for h in heights}
        lines += [_row(f"{s.spec} @ {h:g} m", by_height[h]) for h in heights]
        if len(heights) == 2:
            lines.append(_row(f"{s.spec}: {heights[0]:g} m - {heights[1]:g} m", _difference(by_height[heights[0]], by_height[heights[1]])))
    lines += ["", "## Zero-shot bucket", ""]
    zero = [(s.spec, s.summary()[ZERO_SHOT]) for s in scores]
    if selection == NO_SPLIT:
        lines.append("missing: the run has no split stage output marking zero-shot objects (run `split`, then report again).")
    else:
        lines += _header("model") + [_row(spec, values) for spec, values in zero]
    lines += ["", "## Per frame against self-prompting", ""]
    by_spec = {s.spec: s for s in scores}
    pairs = [(spec, spec + SELF_PROMPTING_SUFFIX) for spec in by_spec if spec + SELF_PROMPTING_SUFFIX in by_spec]
    if pairs:
        lines += _header("model")
        for base, prompted in pairs:
            a, b = by_spec[base].summary()[AGGREGATE], by_spec[prompted].summary()[AGGREGATE]
            lines += [_row(base, a), _row(prompted, b), _row(f"{prompted} - {base}", _difference(b, a))]
        same = [base for base, prompted in pairs if _same_counts(by_spec[base], by_spec[prompted])]
        if same:
            lines += ["", f"{', '.join(same)}: identical counts with and without self-prompting. Expected when the "
                      "segmenter's masks partition each frame (`geometric` with `levels: 1`): every region is either "
                      "selected by a carried prompt or seeds itself, so the set of masks is unchanged; self-prompting "
                      "matters for overlapping masks (`levels: 2`, FastSAM, SAM)."]
    else:
        lines.append("no pair: list a model with and without `+sp` (e.g. geometric,geometric+sp) to compare.")
    lines += ["", "## Pictures", ""] + [f"![{p.stem}]({p.name})" for p in pictures]
    return "\n".join(lines) + "\n"


def _same_counts(a: ModelScores, b: ModelScores) -> bool:
    """Whether two models have the same TP / FP / FN in every video, bucket and k."""
    def counts(s: ModelScores) -> dict[str, Any]:
        return {key: {bucket: {k: (c.tp, c.fp, c.fn) for k, c in per_k.items()} for bucket, per_k in v.buckets.items()}
                for key, v in s.per_video.items()}
    return counts(a) == counts(b)


# ---------------------------------------------------------------------------------- pictures


def _plot_by_k(scores: list[ModelScores], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.5, 3.6))
    width = 0.8 / max(1, len(scores))
    for index, s in enumerate(scores):
        values = s.summary()[AGGREGATE]
        heights = [100 * (values[k] or 0.0) for k in (*KS_LABELS, "VSQ")]
        axes.bar(np.arange(5) + index * width, heights, width, label=s.spec)
    axes.set_xticks(np.arange(5) + 0.4 - width / 2, ["VSQ^1", "VSQ^5", "VSQ^10", "VSQ^15", "VSQ"])
    axes.set_ylabel("percent")
    axes.set_title("VSQ per model")
    axes.legend(fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with replaced(path) as temporary:  # a new file (see `replaced`): never one shared by a hard link
        figure.savefig(temporary, dpi=110, format="png")
    plt.close(figure)
    return path


def _plot_by_height(scores: list[ModelScores], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    heights = _heights(scores)
    figure, axes = plt.subplots(1, len(scores), figsize=(3.2 * len(scores), 3.2), squeeze=False, sharey=True)
    for axis, s in zip(axes[0], scores):
        for h in heights:
            values = s.summary([k for k in s.per_video if video_height_m(k) == h])[AGGREGATE]
            axis.plot([int(k) for k in KS_LABELS], [100 * (values[k] or 0.0) for k in KS_LABELS], marker="o", label=f"{h:g} m")
        axis.set_title(s.spec)
        axis.set_xlabel("k")
        axis.legend(fontsize=8)
    axes[0][0].set_ylabel("VSQ^k, percent")
    figure.tight_layout()
    with replaced(path) as temporary:  # a new file (see `replaced`): never one shared by a hard link
        figure.savefig(temporary, dpi=110, format="png")
    plt.close(figure)
    return path


def _colour_masks(masks: np.ndarray) -> np.ndarray:
    """(n, H, W) masks -> RGB, painted largest first so smaller masks stay visible; black = nothing."""
    palette = np.random.default_rng(7).integers(40, 256, size=(max(1, len(masks)), 3), dtype=np.uint8)
    image = np.zeros((*masks.shape[1:], 3), np.uint8)
    for index in np.argsort([-int(m.sum()) for m in masks], kind="stable"):
        image[masks[index]] = palette[index]
    return image


def _colour_ids(ids: np.ndarray) -> np.ndarray:
    """Id image -> RGB with one fixed colour per id (the same object keeps its colour in every frame); 0 black."""
    unique, inverse = np.unique(ids, return_inverse=True)
    mixed = unique.astype(np.uint64)[:, None] * np.array([2654435761, 2246822519, 3266489917], np.uint64)
    palette = (40 + (mixed >> np.uint64(13)) % np.uint64(216)).astype(np.uint8)
    palette[unique == 0] = 0
    return palette[inverse.reshape(ids.shape)]


def _picture_strip(run: RunFolder, embodiment: str, specs: Sequence[str], out: Path, path: Path) -> Path | None:
    """RGB | ground truth | each model's masks, for four frames of the first video all models predicted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pycocotools.mask as mask_utils

    from pipeline.io.reader import load_video

    folders = [out / "predictions" / spec / RLE_FOLDER for spec in specs]
    names = sorted(set.intersection(*[{p.name for p in f.iterdir()} if f.is_dir() else set() for f in folders]))
    if not names:
        return None
    video = load_video(run, names[0], embodiment)
    frames = sorted({int(i) for i in np.linspace(0, video.frames - 1, 4)})
    columns = 2 + len(specs)
    figure, axes = plt.subplots(len(frames), columns, figsize=(2.4 * columns, 1.9 * len(frames)), squeeze=False)
    for row, t in enumerate(frames):
        images = [np.asarray(video.rgb[t]), _colour_ids(np.asarray(video.panoptic[t]))]
        for folder in folders:
            rles = read_rle_file(folder / names[0] / f"{t:010d}.json")["coco_rle"]
            with warnings.catch_warnings():  # pycocotools' decode warns about NumPy 2's copy keyword, harmlessly
                warnings.simplefilter("ignore", DeprecationWarning)
                masks = (mask_utils.decode([{"size": r["size"], "counts": r["counts"].encode()} for r in rles]).transpose(2, 0, 1)
                         if rles else np.zeros((0, *images[0].shape[:2]), np.uint8))
            images.append(_colour_masks(masks.astype(bool)))
        for column, (axis, image) in enumerate(zip(axes[row], images)):
            axis.imshow(image)
            axis.set_xticks([])
            axis.set_yticks([])
            if row == 0:
                axis.set_title(["RGB", "ground truth", *specs][column], fontsize=9)
        axes[row][0].set_ylabel(f"frame {t}", fontsize=8)
    figure.suptitle(names[0], fontsize=9)
    figure.tight_layout()
    with replaced(path) as temporary:  # a new file (see `replaced`): never one shared by a hard link
        figure.savefig(temporary, dpi=100, format="png")
    plt.close(figure)
    return path
