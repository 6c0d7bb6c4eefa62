"""Training runs of the fall-dynamics model (``train.py`` with a ``kind: fall_dynamics`` config).

Each step samples sequences and a window: ``context`` true frames in, then a
``rollout``-step free-running prediction (probabilities fed back), scored by
cross-entropy plus a soft block IoU -- trained the way it is evaluated, with the
first step (t+1) counted ``1 + next_frame_loss_weight`` times -- plus,
weighted by ``motion_loss_weight``, the distance of each block's predicted
displacement from its true centroid displacement (``block_displacements``;
for an ``anchored`` model, the displacements summed from the newest true frame):
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

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
import yaml

from panda_grasp_env.falls.config import FallConfig, fall_config
from panda_grasp_env.falls.dataset import load_split, read_metadata
from panda_grasp_env.falls.metrics import evaluate, test_scores
from panda_grasp_env.falls.model import (
    ARCHITECTURE,
    FallPredictor,
    block_displacements,
    check_compatible,
    heights,
    load_fall_model,
    model_inputs,
    one_hot,
)
from panda_grasp_env.falls.records import fall_card, plot_fall_curve, write_strips
from panda_grasp_env.tooling.runs import (
    atomic_path,
    check_run_files,
    commit,
    new_run_folder,
    run_key,
    sign_run_files,
    write_atomically,
    write_json,
)


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
    model = FallPredictor(n_classes, size, config.context, config.hidden, config.use_depth, config.anchored_rollout)
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
    schedule = (
        torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, config.epochs, last_epoch=epoch - 1)
        if epoch
        else torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, config.epochs)
    )
    writer = SummaryWriter(str(run_dir / "tb"))
    batches = max(1, len(train.labels) // config.batch_size)
    window = config.context + config.rollout
    began = time.perf_counter()

    def wall() -> float:
        return wall_before + time.perf_counter() - began

    def checkpoint(path: Path) -> None:
        with atomic_path(path) as tmp:
            torch.save(
                {
                    "model": model.state_dict(),
                    "model_args": model.describe(),
                    "classes": train.classes,
                    "architecture": ARCHITECTURE,
                    "optimiser": optimiser.state_dict(),
                    "torch_rng": torch.get_rng_state(),
                    "numpy_rng": rng.bit_generator.state,
                    "epoch": epoch,
                    "wall_seconds": wall(),
                    "best": best,
                    "unvalidated_loss": unvalidated_loss,
                    "frame_interval": train.frame_interval,
                    "label_source": config.label_source,
                },
                tmp,
            )
        sign_run_files(run_dir, [path.name])

    bar = tqdm(
        total=config.epochs * batches,
        initial=epoch * batches,
        unit="batch",
        disable=not progress_bar,
        desc=config.name,
        mininterval=5.0,
    )

    def validate(loss: float) -> None:
        """Score the model on validation after ``epoch``: evaluations.jsonl, TensorBoard, best.pt, latest.pt."""
        nonlocal best, unvalidated_loss
        metrics = evaluate(model, val.labels, val.classes, config.context, depth=val.depth, baselines=False)["model"]
        score = metrics[f"t+{config.select_horizon}"]["mean_block_iou"]
        row = {"epoch": epoch, "wall_seconds": round(wall(), 1), "loss": round(loss, 4), "val": metrics}
        with open(run_dir / "evaluations.jsonl", "a") as log:
            log.write(json.dumps(row) + "\n")
        writer.add_scalar("train/loss", row["loss"], epoch)
        for horizon in ("t+1", "t+5"):
            writer.add_scalar(f"val/mean_block_iou_{horizon}", metrics[horizon]["mean_block_iou"], epoch)
            writer.add_scalar(f"val/foreground_accuracy_{horizon}", metrics[horizon]["foreground_accuracy"], epoch)
        bar.set_postfix_str(
            f"loss {row['loss']:.3f}, val block IoU t+{config.select_horizon} {score:.3f}", refresh=False
        )
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
                    if model.anchored:  # each frame's blocks are the anchor's moved by the displacements so far
                        moved = motions.cumsum(1).flatten(0, 1)
                        before = clips[:, config.context - 1 : config.context].expand(-1, config.rollout, -1, -1)
                    else:
                        moved, before = motions.flatten(0, 1), clips[:, config.context - 1 : -1]
                    loss = loss + config.motion_loss_weight * motion_loss(moved, before.flatten(0, 1), truth)
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
