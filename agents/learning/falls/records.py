"""What a fall-dynamics run leaves besides its checkpoints: strips of predicted frames, the learning curve,
the model card, and the shipped copy of a finished run (``train.py --ship``)."""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from panda_grasp_env.agents.learning.falls.config import FallConfig
from panda_grasp_env.agents.learning.falls.directions import DIRECTION_TOLERANCE, FALL_SHIFT
from panda_grasp_env.agents.learning.falls.model import ARCHITECTURE, FallPredictor, load_fall_model, predict_batch
from panda_grasp_env.falls.shards import read_metadata, tower_heights
from panda_grasp_env.model.scene import DEFAULT_COLOURS
from panda_grasp_env.sim.stability import STILL_SHIFT
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, MAX_LOG_BYTES, read_json, read_json_lines
from panda_grasp_env.tooling.runs import atomic_path, resume_summary

#: Colours of the class maps in strips: background, then the blocks' own colours in the scene's order (up to 8).
PALETTE = np.array(
    [[235, 235, 230], *(np.round(255 * np.array(rgb)) for rgb in DEFAULT_COLOURS.values())], dtype=np.uint8
)


def label_image(labels: np.ndarray, scale: int = 2) -> np.ndarray:
    """An RGB image (S * scale, S * scale, 3) of class labels (S, S) in ``PALETTE``'s colours."""
    image = PALETTE[np.clip(labels, 0, len(PALETTE) - 1)]
    return np.repeat(np.repeat(image, scale, 0), scale, 1)


def write_strips(
    model: FallPredictor, labels: np.ndarray, seeds: np.ndarray, folder: Path, rollout: int, depth: Any = None
) -> None:
    """One PNG per sequence: the context frames, then truth (top) and prediction (bottom) for ``rollout`` steps."""
    import imageio.v3 as iio

    folder.mkdir(parents=True, exist_ok=True)
    k = model.context
    predicted = predict_batch(model, labels[:, :k], rollout, None if depth is None else depth[:, :k])
    gap = np.full((labels.shape[-1] * 2, 4, 3), 255, dtype=np.uint8)
    for sequence, truth, guess, seed in zip(labels, labels[:, k : k + rollout], predicted, seeds):
        inputs = np.concatenate([label_image(f) for f in sequence[:k]], 1)
        blank = np.full_like(inputs, 255)
        top = np.concatenate([inputs, gap, *[label_image(f) for f in truth]], 1)
        bottom = np.concatenate([blank, gap, *[label_image(f) for f in guess]], 1)
        with atomic_path(folder / f"seed{int(seed)}.png") as tmp:
            iio.imwrite(tmp, np.concatenate([top, bottom], 0), extension=".png")


def plot_fall_curve(run_dir: Path) -> None:
    """curve.png: the validation figures of evaluations.jsonl by epoch and by wall time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [row for _, row in read_json_lines(run_dir / "evaluations.jsonl", MAX_LOG_BYTES)]
    figure, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for axis, x, label in (
        (axes[0], [r["epoch"] for r in rows], "epoch"),
        (axes[1], [r["wall_seconds"] / 60 for r in rows], "wall time, minutes"),
    ):
        for horizon in ("t+1", "t+5"):
            axis.plot(
                x, [r["val"][horizon]["mean_block_iou"] for r in rows], marker="o", label=f"mean block IoU {horizon}"
            )
            axis.plot(
                x,
                [r["val"][horizon]["foreground_accuracy"] for r in rows],
                marker="s",
                label=f"foreground acc. {horizon}",
            )
        axis.set_xlabel(label)
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("validation")
    axes[0].legend(loc="lower right", fontsize=8)
    figure.tight_layout()
    with atomic_path(run_dir / "curve.png") as tmp:
        figure.savefig(tmp, dpi=100, format="png")
    plt.close(figure)


def tower_words(heights: list[int]) -> str:
    """``[4]`` -> ``"4-block"``, ``[6, 8]`` -> ``"6- or 8-block"``, ``[4, 6, 8]`` -> ``"4-, 6- or 8-block"``."""
    names = [str(h) for h in heights]
    return ("-, ".join(names[:-1]) + "- or " if len(names) > 1 else "") + f"{names[-1]}-block"


def scene_words(metadata: dict[str, Any]) -> str:
    """What a fall dataset's sequences show, for the card: a falling tower of its heights, or (``--scene
    structures``) partly built structures recorded from rest."""
    if metadata.get("scene") == "structures":
        return f"partly built structure (up to {max(tower_heights(metadata))} pieces, recorded from rest, standing or falling)"
    return f"falling {tower_words(tower_heights(metadata))} tower"


def direction_rows(direction: dict[str, Any]) -> list[str]:
    """The card's fall-direction table (``fall_directions``): each predictor over all towers, then by height."""
    groups = {"all": direction, **{f"{h} blocks": d for h, d in direction.get("by_height", {}).items()}}
    rows = []
    for name in direction["predictors"]:
        for label, group in groups.items():
            r = group["predictors"][name]
            within = "n/a" if r["within_45"] is None else f"**{r['within_45']:.3f}**"
            median = "n/a" if r["median_error_deg"] is None else f"{r['median_error_deg']:.1f}°"
            rows.append(
                f"| {name} | {label} | {group['did_not_fall']} | {group['fell']} | {group['hidden']} | "
                f"{group['scored']} | {within} | {median} | {r['no_direction']} |"
            )
    return rows


def track_head_summary(run_dir: Path) -> str | None:
    """How a run's track head was fitted before the ConvLSTM's epochs (``track_pretraining.json``), if it was."""
    if not (run_dir / "track_pretraining.json").is_file():
        return None
    fitted = read_json(run_dir / "track_pretraining.json", MAX_DOCUMENT_BYTES)
    losses = fitted["validation_loss"]
    return (
        f"track head fitted alone first: {fitted['epochs']} epochs on {fitted['training_rows']} training rows "
        f"(a block in view in a window) in {fitted['seconds'] / 60:.1f} min, validation loss {losses[0]} after the "
        f"first epoch, {losses[-1]} after the last ({fitted['validation_rows']} rows); then frozen; epoch 0 of "
        "the curve is the plan alone"
    )


def settle_summary(final: dict[str, Any]) -> str | None:
    """The settle head's test answers (``final["settle"]``), if the model has one."""
    if "settle" not in final:
        return None
    s = final["settle"]
    return (
        f"settle head (will what was just set stand?), test split at {STILL_SHIFT * 1000:.0f} mm: precision "
        f"{s['precision']:.3f}, recall {s['recall']:.3f}, accuracy {s['accuracy']:.3f} on {s['sequences']} "
        f'sequences ({s["falls"]} fall; always answering "stands": {s["always_stands_accuracy"]:.3f})'
    )


def fall_card(config: FallConfig, run_dir: Path, final: dict[str, Any]) -> str:
    """card.md of a finished run: what was trained on what, the test figures against the baselines, the config."""
    meta = read_json(run_dir / "meta.json", MAX_DOCUMENT_BYTES)
    m, direction = final["metrics"], final["direction"]
    rows = []
    for name in m:
        for horizon in ("t+1", "t+5"):
            r = m[name][horizon]
            iou = ", ".join(f"{k} {v:.3f}" for k, v in r["iou"].items())
            rows.append(
                f"| {name} | {horizon} | {r['pixel_accuracy']:.4f} | {r['foreground_accuracy']:.4f} | "
                f"**{r['mean_block_iou']:.4f}** | {iou} |"
            )
    return "\n".join(
        [
            f"# {config.name}",
            "",
            "ConvLSTM encoder-decoder predicting the next segmentation frames of a "
            f"{scene_words(read_metadata(config.dataset))} "
            "(`agents/learning/falls/model.py`"
            + (", reading depth as well as labels" if config.use_depth else "")
            + "), trained by this repository's `train.py` with the resolved config below on "
            f"`{config.dataset}` ({meta['dataset']['sequences']} sequences, splits {meta['dataset']['splits']}).",
            "",
            f"- seed {config.seed}; {final['epochs']} of {config.epochs} epochs (stopped by {final['stopped_by']}; "
            f"best on validation: epoch {final['best_epoch']}); "
            f"wall time {final['wall_seconds'] / 60:.1f} min on {meta['machine']}",
            f"- commit {meta['commit']}; {', '.join(f'{k} {v}' for k, v in meta['versions'].items())}",
            *([f"- {resumed}"] if (resumed := resume_summary(meta)) else []),
            *([f"- {fitted}"] if (fitted := track_head_summary(run_dir)) else []),
            *([f"- {settled}"] if (settled := settle_summary(final)) else []),
            f"- test: {final['test_sequences']} held-out sequences, every t with {config.context} context frames; "
            f"{m['copy_last']['t+1']['frames']} predictions per horizon",
            "",
            "| predictor | horizon | pixel accuracy | foreground accuracy | mean block IoU | IoU per class |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
            "Which way each test tower fell (the mean position of its blocks in view at the end, world frame, "
            "first frame to last; "
            f"moved under {FALL_SHIFT * 100:.0f} cm: did not fall), predicted from the first {config.context} "
            "frames (the centroid of the block pixels of the predicted last frame minus that of the first; "
            "`fall_directions` in `agents/learning/falls/directions.py`), scored over the towers that fell and that the "
            f"first frame shows (not hidden by the arm): the fraction within ±{DIRECTION_TOLERANCE:.0f}° and the "
            "median angular error, a prediction without a direction counting as 180°; `true_labels` is the true "
            "last frame through the same measure (a reference).",
            "",
            f"| predictor | towers | did not fall | fell | hidden | scored | within ±{DIRECTION_TOLERANCE:.0f}° | "
            "median error | no direction |",
            "|---|---|---|---|---|---|---|---|---|",
            *direction_rows(direction),
            "",
            "![learning curve](curve.png)",
            "",
            "```yaml",
            yaml.safe_dump(dataclasses.asdict(config), sort_keys=False).rstrip(),
            "```",
            "",
        ]
    )


#: Where shipped fall-dynamics models live (``load_fall_model(FALL_CHECKPOINTS / name / "model.pt")``).
FALL_CHECKPOINTS = Path(__file__).resolve().parent / "checkpoints"


def ship_fall_run(run_dir: Path, name: str, strips: int = 5) -> Path:
    """Copy a finished fall run's best model (weights only), card, curve, results and a few strips to
    ``agents/learning/falls/checkpoints/<name>`` (staged, then renamed into place)."""
    run_dir = Path(run_dir)
    missing = [
        f for f in ("best.pt", "final.json", "card.md", "curve.png", "config.yaml") if not (run_dir / f).is_file()
    ]
    if missing:
        raise ValueError(f"{run_dir} is not a finished fall-dynamics run: {missing} missing")
    model, saved = load_fall_model(run_dir / "best.pt")
    staging = FALL_CHECKPOINTS / f".{name}.tmp"
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "strips").mkdir(parents=True)
    torch.save(
        {
            "model": model.state_dict(),
            "model_args": model.describe(),
            "classes": saved["classes"],
            "architecture": ARCHITECTURE,
            "epoch": saved["epoch"],
            "frame_interval": saved["frame_interval"],
            "label_source": saved["label_source"],
        },
        staging / "model.pt",
    )
    for f in ("final.json", "card.md", "curve.png", "config.yaml", "meta.json", "evaluations.jsonl"):
        shutil.copy2(run_dir / f, staging / f)
    for fitted in ("track_pretraining.json", "settle_fitting.json"):  # the heads fitted alone, if they were
        if (run_dir / fitted).is_file():
            shutil.copy2(run_dir / fitted, staging / fitted)
    for strip in sorted((run_dir / "strips").glob("*.png"))[:strips]:
        shutil.copy2(strip, staging / "strips" / strip.name)
    target = FALL_CHECKPOINTS / name
    if target.exists():
        shutil.rmtree(target)
    os.replace(staging, target)
    return target
