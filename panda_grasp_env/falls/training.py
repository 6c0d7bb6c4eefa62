"""Training runs of the fall-dynamics model (``train.py`` with a ``kind: fall_dynamics`` config).

Each step samples sequences and a window: ``context`` true frames in, then a
``rollout``-step free-running prediction (probabilities fed back), scored by
cross-entropy plus a soft block IoU -- trained the way it is evaluated, with the
first step (t+1) counted ``1 + next_frame_loss_weight`` times -- plus,
weighted by ``motion_loss_weight``, the distance of each block's predicted
displacement from its true centroid displacement (``block_displacements``):
through the warp alone, motion gets gradient only at block edges and barely
learns.  With
``use_depth`` the model also reads height maps from the depth images and is
scored, weighted by ``height_loss_weight``, on the heights it predicts (mean
absolute error in blocks).  The run
folder holds config.yaml, meta.json, tb/, evaluations.jsonl (validation
metrics per epoch), curve.png, latest.pt / best.pt (atomic), and at the end
final.json (test metrics and fall directions against the baselines), card.md and
strips/ (one PNG per test sequence: input frames, truth, prediction).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
import yaml

from panda_grasp_env.falls.dataset import FallSequences, load_split, read_metadata, tower_heights
from panda_grasp_env.falls.model import (
    ARCHITECTURE,
    DIRECTION_TOLERANCE,
    FALL_SHIFT,
    FallPredictor,
    block_displacements,
    check_compatible,
    evaluate,
    fall_directions,
    heights,
    model_inputs,
    one_hot,
    predict_batch,
)
from panda_grasp_env.model.scene import DEFAULT_COLOURS
from panda_grasp_env.tooling.runs import (
    atomic_path,
    check_run_files,
    commit,
    config_from_mapping,
    new_run_folder,
    resume_summary,
    run_key,
    sign_run_files,
    write_atomically,
    write_json,
)

#: Colours of the class maps in strips: background, then the blocks' own colours in the scene's order (up to 8).
PALETTE = np.array([[235, 235, 230], *(np.round(255 * np.array(rgb)) for rgb in DEFAULT_COLOURS.values())],
                   dtype=np.uint8)  # fmt: skip


@dataclass
class FallConfig:
    """A fall-dynamics training run.  ``dataset``: a folder written by ``python -m panda_grasp_env.falls``."""

    kind: str
    name: str
    dataset: str
    label_source: str = "labels"  # labels (simulator) | colour_labels (perception's colour segmentation)
    context: int = 4
    rollout: int = 5
    hidden: int = 32
    epochs: int = 30
    batch_size: int = 16
    learning_rate: float = 0.002
    motion_loss_weight: float = 1.0
    next_frame_loss_weight: float = 0.0  # extra weight of the t+1 prediction's loss (the headline metric)
    use_depth: bool = False  # also read the depth images (height maps; see panda_grasp_env/falls/model.py)
    height_loss_weight: float = 1.0
    seed: int = 0
    max_minutes: float | None = None
    torch_threads: int = 2

    def validate(self) -> None:
        for key in ("context", "rollout", "hidden", "epochs", "batch_size", "torch_threads"):
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"config {key}={value!r}: expected an int >= 1")
        if self.kind != "fall_dynamics":
            raise ValueError(f"config kind={self.kind!r}: expected 'fall_dynamics'")
        if self.label_source not in ("labels", "colour_labels"):
            raise ValueError(f"config label_source={self.label_source!r}: expected 'labels' or 'colour_labels'")
        if not (isinstance(self.learning_rate, (int, float)) and 0 < self.learning_rate < 1):
            raise ValueError(f"config learning_rate={self.learning_rate!r}: expected a number in (0, 1)")
        for key in ("motion_loss_weight", "next_frame_loss_weight", "height_loss_weight"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0):
                raise ValueError(f"config {key}={value!r}: expected a number >= 0")
        if not isinstance(self.use_depth, bool):
            raise ValueError(f"config use_depth={self.use_depth!r}: expected true or false")
        if self.max_minutes is not None and not self.max_minutes > 0:
            raise ValueError(f"config max_minutes={self.max_minutes!r}: expected a positive number or null")
        read_metadata(self.dataset)  # a clear error now, not after the model is built


#: What ``--resume`` may change in a fall-dynamics run; every other key built its model, data or optimiser.
FALL_RESUME_CHANGEABLE = ("epochs", "max_minutes", "torch_threads")


def fall_config(raw: dict[str, Any], source: str) -> FallConfig:
    return config_from_mapping(FallConfig, raw, source)


def prediction_loss(logits: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """Cross-entropy plus a soft-IoU term on the block classes (the metric: blocks are ~2 % of pixels each,
    and class weights instead would trade IoU for false positives).  ``logits`` (N, C, S, S), ``truth`` (N, S, S)."""
    probabilities = torch.softmax(logits, 1)[:, 1:]
    target = one_hot(truth, logits.shape[1])[:, 1:]
    intersection = (probabilities * target).sum((0, 2, 3))
    union = (probabilities + target - probabilities * target).sum((0, 2, 3))
    soft_iou = (intersection / union.clamp_min(1.0)).mean()
    return F.cross_entropy(logits, truth.long()) + (1.0 - soft_iou)


def motion_loss(displacements: torch.Tensor, before: torch.Tensor, after: torch.Tensor) -> torch.Tensor:
    """Distance in pixels (smooth below 0.1 px) of predicted block displacements (N, K, 2) from the blocks'
    centroid displacements between true frames ``before`` and ``after`` (N, S, S), weighted by each block's
    area in ``after`` (as the IoU weighs it).  In pixels: blocks move ~1 px a frame on average, and a
    sub-pixel error costs IoU."""
    target, area = block_displacements(before, after)
    distance = F.smooth_l1_loss(displacements, target, reduction="none", beta=0.1).sum(2)
    return (distance * area).sum() / area.sum().clamp_min(1.0)


def load_fall_model(path: Path | str) -> tuple[FallPredictor, dict[str, Any]]:
    """A trained model and its saved facts (classes, image size, context) from a ``.pt`` checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"fall-dynamics checkpoint {path} not found")
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)  # tensors and plain data: nothing runs
    except Exception as error:
        raise ValueError(f"cannot load fall-dynamics checkpoint {path}: {error}") from error
    if saved.get("architecture") != ARCHITECTURE:
        raise ValueError(
            f"fall-dynamics checkpoint {path} is of model architecture {saved.get('architecture', 1)}; "
            f"this code runs architecture {ARCHITECTURE}: retrain it with train.py"
        )
    try:
        model = FallPredictor(**saved["model_args"])
        model.load_state_dict(saved["model"])
    except Exception as error:
        raise ValueError(f"cannot load fall-dynamics checkpoint {path}: {error}") from error
    return model, saved


def label_image(labels: np.ndarray, scale: int = 2) -> np.ndarray:
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


def test_scores(model: FallPredictor, test: FallSequences, context: int) -> dict[str, Any]:
    """The test figures of ``model`` and the baselines on a split: ``metrics`` (``evaluate``) and ``direction``
    (``fall_directions``)."""
    return {
        "metrics": evaluate(model, test.labels, test.classes, context, depth=test.depth),
        "direction": fall_directions(
            model,
            test.labels,
            test.poses,
            test.n_blocks,
            test.crop_origin,
            test.camera,
            test.classes,
            context,
            test.depth,
        ),
    }


def start_fall_run(config: FallConfig, runs_dir: Path) -> Path:
    """A fresh run folder with config.yaml and meta.json (which also names the dataset)."""
    dataset = read_metadata(config.dataset)
    facts = {"path": config.dataset, "sequences": dataset["sequences"], "splits": dataset["splits"]}
    return new_run_folder(runs_dir, config, dataset=facts)


def train_fall_model(
    config: FallConfig, run_dir: Path, resume: bool = False, progress_bar: bool = True, trust: bool = False
) -> dict[str, Any]:
    """Train (or continue) to ``config.epochs``; Ctrl-C saves latest.pt and re-raises.  A resume loads
    latest.pt only as tensors and plain data, and only if this user's job signed it in this folder
    (``runs.check_run_files``) or with ``trust=True``."""
    from torch.utils.tensorboard import SummaryWriter
    from tqdm import tqdm

    torch.set_num_threads(config.torch_threads)
    run_key()  # the key that signs its checkpoints: one others could know stops the run now, not at its first save
    train = load_split(config.dataset, "train", config.label_source, depth=config.use_depth)
    val = load_split(config.dataset, "val", config.label_source, verify=False, depth=config.use_depth)
    n_classes, size = len(train.classes), train.image_size
    if train.labels.shape[1] < config.context + config.rollout:
        raise ValueError(
            f"sequences have {train.labels.shape[1]} frames; context + rollout needs {config.context + config.rollout}"
        )
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    model = FallPredictor(n_classes, size, config.context, config.hidden, config.use_depth)
    optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate)
    epoch, wall_before, best = 0, 0.0, -1.0
    unvalidated_loss = None  # the last epoch's training loss while its validation has not run
    if resume:
        if not trust:
            check_run_files(run_dir, ["latest.pt"])
        try:
            saved = torch.load(run_dir / "latest.pt", map_location="cpu", weights_only=True)
        except Exception as error:  # a truncated file, or one holding more than tensors and plain data
            raise ValueError(f"cannot resume {run_dir} from latest.pt: {error}") from error
        model.load_state_dict(saved["model"])
        optimiser.load_state_dict(saved["optimiser"])
        torch.set_rng_state(saved["torch_rng"])
        rng.bit_generator.state = saved["numpy_rng"]
        epoch, wall_before, best = saved["epoch"], saved["wall_seconds"], saved["best"]
        unvalidated_loss = saved.get("unvalidated_loss")
    check_compatible(model, train.labels, train.classes, train.depth)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, config.epochs, last_epoch=epoch - 1) if epoch else \
        torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, config.epochs)  # fmt: skip
    writer = SummaryWriter(str(run_dir / "tb"))
    batches = max(1, len(train.labels) // config.batch_size)
    window = config.context + config.rollout
    began = time.perf_counter()

    def wall() -> float:
        return wall_before + time.perf_counter() - began

    def checkpoint(path: Path) -> None:
        with atomic_path(path) as tmp:
            torch.save({"model": model.state_dict(), "model_args": model.describe(), "classes": train.classes,
                        "architecture": ARCHITECTURE,
                        "optimiser": optimiser.state_dict(), "torch_rng": torch.get_rng_state(),
                        "numpy_rng": rng.bit_generator.state, "epoch": epoch, "wall_seconds": wall(), "best": best,
                        "unvalidated_loss": unvalidated_loss,
                        "frame_interval": train.frame_interval, "label_source": config.label_source}, tmp)  # fmt: skip
        sign_run_files(run_dir, [path.name])

    bar = tqdm(total=config.epochs * batches, initial=epoch * batches, unit="batch", disable=not progress_bar,
               desc=config.name, mininterval=5.0)  # fmt: skip

    def validate(loss: float) -> None:
        """Score the model on validation after ``epoch``: evaluations.jsonl, TensorBoard, best.pt, latest.pt."""
        nonlocal best, unvalidated_loss
        metrics = evaluate(model, val.labels, val.classes, config.context, depth=val.depth, baselines=False)["model"]
        score = metrics["t+1"]["mean_block_iou"]
        row = {"epoch": epoch, "wall_seconds": round(wall(), 1), "loss": round(loss, 4), "val": metrics}
        with open(run_dir / "evaluations.jsonl", "a") as log:
            log.write(json.dumps(row) + "\n")
        writer.add_scalar("train/loss", row["loss"], epoch)
        for horizon in ("t+1", "t+5"):
            writer.add_scalar(f"val/mean_block_iou_{horizon}", metrics[horizon]["mean_block_iou"], epoch)
            writer.add_scalar(f"val/foreground_accuracy_{horizon}", metrics[horizon]["foreground_accuracy"], epoch)
        bar.set_postfix_str(f"loss {row['loss']:.3f}, val block IoU t+1 {score:.3f}", refresh=False)
        unvalidated_loss = None
        if score > best:
            best = score
            checkpoint(run_dir / "best.pt")
        checkpoint(run_dir / "latest.pt")
        plot_fall_curve(run_dir)

    try:
        if unvalidated_loss is not None:  # interrupted during that epoch's validation
            validate(unvalidated_loss)
        while epoch < config.epochs:
            # Start no epoch that would end past the budget (at the mean epoch's duration so far).
            if config.max_minutes is not None and wall() * (1 + 1 / max(epoch, 1)) >= 60 * config.max_minutes:
                break
            model.train()
            losses = []
            for _ in range(batches):
                chosen = rng.integers(len(train.labels), size=config.batch_size)
                starts = rng.integers(train.labels.shape[1] - window + 1, size=config.batch_size)
                clips = torch.as_tensor(np.stack([train.labels[i, s : s + window] for i, s in zip(chosen, starts)]))
                depths = None
                if config.use_depth:
                    depths = torch.as_tensor(np.stack([train.depth[i, s : s + window] for i, s in zip(chosen, starts)]))
                inputs = model_inputs(
                    model, clips[:, : config.context], None if depths is None else depths[:, : config.context]
                )
                logits, motions, predicted_heights = model.rollout_with_motion(inputs, config.rollout)
                truth = clips[:, config.context :].flatten(0, 1)
                loss = prediction_loss(logits.flatten(0, 1), truth)
                if config.next_frame_loss_weight:
                    loss = loss + config.next_frame_loss_weight * prediction_loss(
                        logits[:, 0], clips[:, config.context]
                    )
                if predicted_heights is not None and config.height_loss_weight:
                    true_heights = heights(depths[:, config.context :])
                    loss = loss + config.height_loss_weight * (predicted_heights - true_heights).abs().mean()
                if config.motion_loss_weight:
                    before = clips[:, config.context - 1 : -1].flatten(0, 1)
                    loss = loss + config.motion_loss_weight * motion_loss(motions.flatten(0, 1), before, truth)
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
                losses.append(loss.item())
                bar.update(1)
            schedule.step()
            epoch += 1
            unvalidated_loss = float(np.mean(losses))
            validate(unvalidated_loss)
    except KeyboardInterrupt:
        checkpoint(run_dir / "latest.pt")
        raise
    finally:
        bar.close()
        writer.close()
    if epoch == 0:
        raise ValueError(f"max_minutes={config.max_minutes} ended {run_dir} before its first epoch")
    # A run ends after its epochs or when its time budget (max_minutes) is spent; both are final.
    return finish_fall_run(config, run_dir, wall(), epoch, "epochs" if epoch >= config.epochs else "max_minutes")


def finish_fall_run(
    config: FallConfig, run_dir: Path, wall_seconds: float, epochs_done: int, stopped_by: str
) -> dict[str, Any]:
    """Test the best checkpoint against the baselines: final.json, card.md, strips/."""
    model, saved = load_fall_model(run_dir / "best.pt")
    test = load_split(config.dataset, "test", config.label_source, verify=False, depth=model.use_depth)
    began = time.perf_counter()
    scores = test_scores(model, test, config.context)
    write_strips(model, test.labels, test.seeds, run_dir / "strips", config.rollout, test.depth)
    final = {
        "epochs": epochs_done,
        "stopped_by": stopped_by,
        "best_epoch": int(saved["epoch"]),
        "wall_seconds": round(wall_seconds, 1),
        "test_sequences": int(len(test.labels)),
        "evaluation_seconds": round(time.perf_counter() - began, 1),
        **scores,
    }
    write_json(run_dir / "final.json", final)
    write_atomically(run_dir / "card.md", fall_card(config, run_dir, final))
    return final


def test_fall_model(folder: Path | str, dataset: str | None = None) -> dict[str, Any]:
    """Score the model of a fall run (``best.pt``) or shipped checkpoint (``model.pt``) against the baselines on
    the test split of ``dataset`` (default: the dataset it was trained on).  Adds the result to the folder's
    retest.json, keyed by dataset; ``ValueError`` if the dataset's images or classes do not fit the model."""
    folder = Path(folder)
    weights = folder / ("best.pt" if (folder / "best.pt").is_file() else "model.pt")
    if not weights.is_file() or not (folder / "config.yaml").is_file():
        raise ValueError(f"{folder} is not a fall-dynamics run or checkpoint (best.pt or model.pt, config.yaml)")
    config = fall_config(yaml.safe_load((folder / "config.yaml").read_text()), str(folder / "config.yaml"))
    model, saved = load_fall_model(weights)
    path = dataset or config.dataset
    test = load_split(path, "test", saved.get("label_source", config.label_source), depth=model.use_depth)
    check_compatible(model, test.labels, test.classes, test.depth)
    began = time.perf_counter()
    result = {
        "dataset": str(path),
        "weights": weights.name,
        "test_sequences": int(len(test.labels)),
        "test_commit": commit(),
        **test_scores(model, test, model.context),
    }
    result["evaluation_seconds"] = round(time.perf_counter() - began, 1)
    record = folder / "retest.json"
    results = json.loads(record.read_text()) if record.is_file() else {}
    write_json(record, {**results, str(path): result})
    return result


def plot_fall_curve(run_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(line) for line in (run_dir / "evaluations.jsonl").read_text().splitlines() if line.strip()]
    figure, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for axis, x, label in ((axes[0], [r["epoch"] for r in rows], "epoch"),
                           (axes[1], [r["wall_seconds"] / 60 for r in rows], "wall time, minutes")):  # fmt: skip
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


def direction_rows(direction: dict[str, Any]) -> list[str]:
    """The card's fall-direction table (``fall_directions``): each predictor over all towers, then by height."""
    groups = {"all": direction, **{f"{h} blocks": d for h, d in direction.get("by_height", {}).items()}}
    rows = []
    for name in direction["predictors"]:
        for label, group in groups.items():
            r = group["predictors"][name]
            within = "n/a" if r["within_45"] is None else f"**{r['within_45']:.3f}**"
            median = "n/a" if r["median_error_deg"] is None else f"{r['median_error_deg']:.1f}°"
            rows.append(f"| {name} | {label} | {group['did_not_fall']} | {group['fell']} | {group['hidden']} | "
                        f"{group['scored']} | {within} | {median} | {r['no_direction']} |")  # fmt: skip
    return rows


def fall_card(config: FallConfig, run_dir: Path, final: dict[str, Any]) -> str:
    meta = json.loads((run_dir / "meta.json").read_text())
    m, direction = final["metrics"], final["direction"]
    rows = []
    for name in m:
        for horizon in ("t+1", "t+5"):
            r = m[name][horizon]
            iou = ", ".join(f"{k} {v:.3f}" for k, v in r["iou"].items())
            rows.append(f"| {name} | {horizon} | {r['pixel_accuracy']:.4f} | {r['foreground_accuracy']:.4f} | "
                        f"**{r['mean_block_iou']:.4f}** | {iou} |")  # fmt: skip
    return "\n".join(
        [
            f"# {config.name}",
            "",
            "ConvLSTM encoder-decoder predicting the next segmentation frames of a falling "
            f"{tower_words(tower_heights(read_metadata(config.dataset)))} tower "
            "(`panda_grasp_env/falls/model.py`"
            + (", reading depth as well as labels" if config.use_depth else "")
            + "), trained by this repository's `train.py` with the resolved config below on "
            f"`{config.dataset}` ({meta['dataset']['sequences']} sequences, splits {meta['dataset']['splits']}).",
            "",
            f"- seed {config.seed}; {final['epochs']} of {config.epochs} epochs (stopped by {final['stopped_by']}; "
            f"best on validation: epoch {final['best_epoch']}); "
            f"wall time {final['wall_seconds'] / 60:.1f} min on {meta['machine']}",
            f"- commit {meta['commit']}; {', '.join(f'{k} {v}' for k, v in meta['versions'].items())}",
            *([f"- {resumed}"] if (resumed := resume_summary(meta)) else []),
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
            "`fall_directions` in `panda_grasp_env/falls/model.py`), scored over the towers that fell and that the "
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
    ``panda_grasp_env/falls/checkpoints/<name>`` (staged, then renamed into place)."""
    import shutil

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
    torch.save({"model": model.state_dict(), "model_args": model.describe(), "classes": saved["classes"],
                "architecture": ARCHITECTURE, "epoch": saved["epoch"], "frame_interval": saved["frame_interval"],
                "label_source": saved["label_source"]}, staging / "model.pt")  # fmt: skip
    for f in ("final.json", "card.md", "curve.png", "config.yaml", "meta.json", "evaluations.jsonl"):
        shutil.copy2(run_dir / f, staging / f)
    for strip in sorted((run_dir / "strips").glob("*.png"))[:strips]:
        shutil.copy2(strip, staging / "strips" / strip.name)
    target = FALL_CHECKPOINTS / name
    if target.exists():
        shutil.rmtree(target)
    os.replace(staging, target)
    return target
