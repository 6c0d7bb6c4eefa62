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
absolute error in blocks).  With ``track_pretrain_epochs`` the model's track
head is fitted alone first (``pretrain_track_head``: every window of every
training sequence, in minutes), validated as epoch 0, and frozen while the
ConvLSTM's epochs train the rest.  With ``settle_epochs`` a settle head
(``settling``) is fitted next, on each training sequence's first frame, and
frozen likewise.  The run folder holds config.yaml, meta.json, tb/,
track_pretraining.json, settle_fitting.json, evaluations.jsonl (validation
metrics per epoch), curve.png, latest.pt / best.pt (atomic), and at the end
final.json (test metrics and fall directions against the baselines), card.md and
strips/ (one PNG per test sequence: input frames, truth, prediction).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from panda_grasp_env.agents.learning.falls.config import FallConfig, fall_config
from panda_grasp_env.agents.learning.falls.dataset import FallSequences, load_split
from panda_grasp_env.agents.learning.falls.metrics import evaluate, test_scores
from panda_grasp_env.agents.learning.falls.model import (
    ARCHITECTURE,
    FallPredictor,
    block_displacements,
    check_compatible,
    heights,
    load_fall_model,
    model_inputs,
    one_hot,
)
from panda_grasp_env.agents.learning.falls.records import fall_card, plot_fall_curve, write_strips
from panda_grasp_env.agents.learning.falls.settling import fit_settle_head
from panda_grasp_env.agents.learning.falls.tracks import SEEN_AREA, TrackHead, block_tracks, track_features
from panda_grasp_env.falls.shards import read_metadata
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json, read_yaml
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
    target, area = block_displacements(before, after, displacements.shape[1] + 1)
    distance = F.smooth_l1_loss(displacements, target, reduction="none", beta=0.1).sum(2)
    return (distance * area).sum() / area.sum().clamp_min(1.0)


def track_windows(
    model: FallPredictor, split: FallSequences, horizon: int, chunk: int = 32, from_rest: bool = False
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The track head's inputs and targets over every window of a split (t with ``model.context`` frames up to
    t and at least one after it), one row per block in view at t: features (N, F), displacements from t to
    t + 1 ... t + ``horizon`` (N, horizon, 2; pixels, x then y) and whether the block is in view at each of
    those frames (N, horizon; false past the sequence's end), and where each row is from (N, 3: sequence, t,
    block class - 1).  ``from_rest``: the sequences start at rest, so the first frame also stands for the
    context frames before it, and windows start at t = 0 (the first one is that frame repeated, what the
    learned stability check gives the model)."""
    context, length = model.context, split.labels.shape[1]
    before = context - 1 if from_rest else 0  # copies of the first frame put in front
    features, targets, seen_later, where = [], [], [], []
    for first in range(0, len(split.labels), chunk):
        depth = None if split.depth is None else split.depth[first : first + chunk]
        frames = model_inputs(model, split.labels[first : first + chunk], depth if model.use_depth else None)
        centre, area, height = block_tracks(frames, model.n_classes)
        if before:
            centre, area, height = (
                torch.cat([track[:, :1].expand(-1, before, *track.shape[2:]), track], 1)
                for track in (centre, area, height)
            )
        seen = F.pad(area > SEEN_AREA, (0, 0, 0, horizon))  # never in view past the end
        centre = F.pad(centre, (0, 0, 0, 0, 0, horizon))
        for t in range(max(context - 1, 1), before + length - 1):
            window, ahead = slice(t - context + 1, t + 1), slice(t + 1, t + 1 + horizon)
            rows = seen[:, t]
            features.append(
                track_features(centre[:, window], area[:, window], height[:, window], model.image_size)[rows]
            )
            targets.append((centre[:, ahead] - centre[:, t, None]).transpose(1, 2)[rows])
            seen_later.append(seen[:, ahead].transpose(1, 2)[rows].float())
            sequence, block = rows.nonzero(as_tuple=True)
            where.append(torch.stack([sequence + first, torch.full_like(sequence, t - before), block], 1))
    return torch.cat(features), torch.cat(targets), torch.cat(seen_later), torch.cat(where)


def fit_track_head(
    head: TrackHead,
    train: tuple[torch.Tensor, ...],
    val: tuple[torch.Tensor, ...],
    epochs: int,
    batch_size: int = 256,
) -> list[float]:
    """Fit a track head alone (``epochs`` epochs, Adam 1e-3 on a cosine schedule) to the block displacements
    of ``track_windows`` rows ``train`` (smooth L1 in pixels over the frames where the block is in view), its
    inputs standardised by those rows' mean and spread; returns each epoch's loss on the rows ``val``."""
    x, y, weight = train[:3]
    head.mean.copy_(x.mean(0))
    head.scale.copy_(x.std(0) + 1e-6)
    parameters = list(head.network.parameters())
    for parameter in parameters:
        parameter.requires_grad_(True)
    optimiser = torch.optim.Adam(parameters, lr=1e-3)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, epochs)

    def loss_of(rows: torch.Tensor, truth: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
        error = F.smooth_l1_loss(head(rows[:, None])[:, 0], truth, reduction="none").sum(2)
        return (error * seen).sum() / seen.sum().clamp_min(1.0)

    validation = []
    for _ in range(epochs):
        for batch in torch.randperm(len(x)).split(batch_size):
            loss = loss_of(x[batch], y[batch], weight[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        schedule.step()
        with torch.no_grad():
            validation.append(round(float(loss_of(*val[:3])), 4))
    for parameter in parameters:
        parameter.requires_grad_(False)
    return validation


def pretrain_track_head(
    model: FallPredictor, train: FallSequences, val: FallSequences, epochs: int, from_rest: bool = False
) -> dict[str, Any]:
    """``fit_track_head`` of ``model.tracks`` on every window of the training and validation splits
    (``track_windows``'s ``from_rest``): the rows counted, each epoch's validation loss and the seconds spent."""
    began = time.perf_counter()
    rows = track_windows(model, train, model.tracks.horizon, from_rest=from_rest)
    val_rows = track_windows(model, val, model.tracks.horizon, from_rest=from_rest)
    return {
        "epochs": epochs,
        "training_rows": len(rows[0]),
        "validation_rows": len(val_rows[0]),
        "validation_loss": fit_track_head(model.tracks, rows, val_rows, epochs),
        "seconds": round(time.perf_counter() - began, 1),
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
    # Planned as far as a rollout from the first frames reaches (the fall direction is read at the last frame).
    track_horizon = train.labels.shape[1] - config.context if config.track_head else 0
    model = FallPredictor(
        n_classes,
        size,
        config.context,
        config.hidden,
        config.use_depth,
        config.anchored_rollout,
        track_horizon,
        # How far blocks went by the last frame: what the stability check asks.
        train.labels.shape[1] - 1 if config.settle_epochs else 0,
    )
    if config.track_pretrain_epochs:  # fitted before the first epoch, then frozen
        model.tracks.requires_grad_(False)
    if config.settle_epochs:
        model.settle.requires_grad_(False)
    optimiser = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=config.learning_rate)
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
    # Cosine from the learning rate to 0 over config.epochs, in closed form from the epoch reached: a resume with
    # more epochs goes on from where that longer schedule would be (a recursive cosine would stay at the 0 it
    # ended on).
    for group in optimiser.param_groups:
        group["initial_lr"] = config.learning_rate
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda done: 0.5 * (1 + math.cos(math.pi * min(done, config.epochs) / config.epochs)), epoch - 1
    )
    writer = SummaryWriter(str(run_dir / "tb"))
    batches = max(1, (config.epoch_sequences or len(train.labels)) // config.batch_size)
    val_labels, val_depth = (
        val.labels[: config.val_sequences],
        None if val.depth is None else val.depth[: config.val_sequences],
    )
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

    def validate(loss: float | None) -> None:
        """Score the model on validation after ``epoch`` (its training loss; None for the fitted track head
        before the first epoch): evaluations.jsonl, TensorBoard, best.pt, latest.pt."""
        nonlocal best, unvalidated_loss
        metrics = evaluate(model, val_labels, val.classes, config.context, depth=val_depth, baselines=False)["model"]
        score = metrics[f"t+{config.select_horizon}"]["mean_block_iou"]
        row = {"epoch": epoch, "wall_seconds": round(wall(), 1), "loss": None, "val": metrics}
        if loss is not None:
            row["loss"] = round(loss, 4)
            writer.add_scalar("train/loss", row["loss"], epoch)
        with open(run_dir / "evaluations.jsonl", "a") as log:
            log.write(json.dumps(row) + "\n")
        for horizon in ("t+1", "t+5"):
            writer.add_scalar(f"val/mean_block_iou_{horizon}", metrics[horizon]["mean_block_iou"], epoch)
            writer.add_scalar(f"val/foreground_accuracy_{horizon}", metrics[horizon]["foreground_accuracy"], epoch)
        bar.set_postfix_str(f"loss {row['loss']}, val block IoU t+{config.select_horizon} {score:.3f}", refresh=False)
        unvalidated_loss = None
        if score > best:
            best = score
            checkpoint(run_dir / "best.pt")
        checkpoint(run_dir / "latest.pt")
        plot_fall_curve(run_dir)

    try:
        if config.track_pretrain_epochs and not resume:
            write_json(
                run_dir / "track_pretraining.json",
                pretrain_track_head(model, train, val, config.track_pretrain_epochs, config.track_windows_from_rest),
            )
        if config.settle_epochs and not resume:
            write_json(run_dir / "settle_fitting.json", fit_settle_head(model, train, val, config.settle_epochs))
        if (config.track_pretrain_epochs or config.settle_epochs) and not resume:
            validate(None)  # the fitted heads, the ConvLSTM untrained (no correction): best.pt unless an epoch beats it
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
    config = fall_config(read_yaml(folder / "config.yaml", MAX_DOCUMENT_BYTES), str(folder / "config.yaml"))
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
    results = read_json(record, MAX_DOCUMENT_BYTES) if record.is_file() else {}
    write_json(record, {**results, str(path): result})
    return result
