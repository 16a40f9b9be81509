"""Training the student, top to bottom (SPEC §7).

    sumo-scimm train --data data/train --val data/val --teacher none  --out runs/student_baseline
    sumo-scimm train --data data/train --val data/val --teacher scimm --seed 1 --out runs/student_scimm

Story: seed -> data (cached BEVs, teacher files) -> model -> optimizer -> loop (pure
learning-rate schedule, validation loss averaged under no_grad after every epoch) -> save.

Schedule (fixed, the same for every arm): AdamW (betas 0.9/0.95, weight decay 0.01 on
matrices and kernels only), batch 128, learning rate linear warm-up over WARMUP_STEPS to
LR, then cosine decay to MIN_LR at the last step; gradient norm clipped to 1.0. Samples
are drawn per epoch as the data balance below says, in a seeded random order; with
probability AUG_PROB a frame is seen from an augmented view (model.cache), with
probability CUT_PROB its route is cut ahead (model.data, route-end augmentation); a
repeated frame keeps its view and cut within the epoch.

Data balance: 38 % of the recorded frames show the expert standing and still standing 2.5 s
later (red lights, stop signs, queues), 6 % standing and then starting off. A student
without memory cannot tell "just arrived" from "waited long enough", learns to stay once
stopped and never starts again (in closed loop, a student trained on every frame stands
55-76 % of the time and moves only when the 40 s creep rule fires). So each epoch draws:
- no standing-and-staying frame while the expert waits at a stop sign (a third of them):
  from one BEV the wait is pure ambiguity, while the frames that approach the sign (moving)
  still teach the student to stop there and the speed input then tells it it has stopped;
- KEEP_STAY of the other standing-and-staying frames (a new seeded subset every epoch);
- every starting-off frame (standing, moved >= 0.5 m 2.5 s later) DEPART_REPEAT times;
- every other frame once.

Teacher arms (``--teacher fixed|scimm|smoother``) add the teacher terms of eq. 11 and the mode term
of eq. 13 with model.loss.LossWeights; ``--teacher none`` is the baseline (l_scimm = l_mode
= 0) and never opens teacher files. The validation loss is L_origin (expert path + speed
waypoints, no augmentation) on the validation dataset, the same for every arm.

Determinism: torch.manual_seed(seed), deterministic algorithms, a fixed thread count, and
one numpy generator (seed) for sample order and views: same seed, same data -> same weights.
The model saved is the one after the last step (not a "best" one).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from harness.common.errors import BadInput
from model.checkpoint import WEIGHTS_NAME, git_commit, save_checkpoint
from model.data import TEACHER_METHODS, StudentData
from model.loss import BASELINE, LossWeights, total_loss
from model.network import NetConfig, Student, n_params

BATCH = 128
LR = 1e-3  # peak learning rate
MIN_LR = 2e-5  # at the last step
WARMUP_STEPS = 200
WEIGHT_DECAY = 0.01
GRAD_CLIP = 1.0
AUG_PROB = 0.5  # share of samples seen from an augmented view
VIEWS = 2  # cached views per frame: as recorded + one augmented
KEEP_STAY = 0.15  # share of standing frames (StudentData.staying) drawn per epoch
DEPART_REPEAT = 3  # draws per epoch of a starting-off frame (StudentData.departing)
CUT_PROB = 0.1  # share of samples with the route cut ahead (route-end augmentation)
CUT_RANGE = (4.0, 30.0)  # [m] the cut distance, uniform
EPOCHS = 5  # default: about 3 min on 2 quiet cores for 67k frames (docs/results.md)
THREADS = 2  # torch threads (fixed, so results do not depend on the machine's core count)


@dataclass(frozen=True)
class TrainConfig:
    data: Path
    out: Path
    teacher: str = "none"  # none | fixed | scimm | smoother
    val: Path | None = None
    seed: int = 0
    epochs: int = EPOCHS
    cache_dir: Path | None = None  # default: <data>/cache (BEV cache, shared by trainings)
    max_steps: int | None = None  # stop early (tests, benchmarks); None = all epochs
    threads: int = THREADS
    net: NetConfig = field(default_factory=NetConfig)
    weights: LossWeights = field(default_factory=LossWeights)

    def __post_init__(self) -> None:
        if self.teacher not in ("none", *TEACHER_METHODS):
            raise BadInput(f"--teacher must be none, {', '.join(TEACHER_METHODS)}, got {self.teacher!r}")
        if self.epochs < 1:
            raise BadInput(f"--epochs must be >= 1, got {self.epochs}")
        if self.seed < 0:
            raise BadInput(f"--seed must be >= 0, got {self.seed}")
        if self.threads < 1:
            raise BadInput(f"threads must be >= 1, got {self.threads}")

    @property
    def loss_weights(self) -> LossWeights:
        return BASELINE if self.teacher == "none" else self.weights


def epoch_plan(data: StudentData, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One epoch: sample order (the data balance above), view and route cut [m, 0 = none]
    of every frame."""
    n = len(data)
    stay = data.staying()
    keep = ~stay | ((rng.random(n) < KEEP_STAY) & ~data.stop_sign())
    extra = np.repeat(np.flatnonzero(data.departing()), DEPART_REPEAT - 1)
    order = rng.permutation(np.concatenate([np.flatnonzero(keep), extra]))
    views = np.where(rng.random(n) < AUG_PROB, rng.integers(1, data.views, n), 0) if data.views > 1 \
        else np.zeros(n, int)
    cuts = np.where(rng.random(n) < CUT_PROB, rng.uniform(*CUT_RANGE, n), 0.0)
    return order, views, cuts


def get_lr(step: int, total: int) -> float:
    """Learning rate at optimizer step ``step`` of ``total``."""
    if step < WARMUP_STEPS:  # 1) linear warm-up
        return LR * (step + 1) / WARMUP_STEPS
    if step >= total - 1:  # 2) the end of the schedule
        return MIN_LR
    ratio = (step - WARMUP_STEPS) / max(1, total - 1 - WARMUP_STEPS)  # 3) cosine decay to MIN_LR
    return MIN_LR + 0.5 * (1.0 + math.cos(math.pi * ratio)) * (LR - MIN_LR)


def forward(model: Student, b: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return model(b["bev"], b["target_point"], b["speed"])


@torch.no_grad()
def estimate_loss(model: Student, data: StudentData, batch: int = 256) -> dict[str, float]:
    """Mean L_origin terms over every frame of ``data`` (view 0), in eval mode."""
    model.eval()
    sums: dict[str, float] = {}
    for lo in range(0, len(data), batch):
        idx = np.arange(lo, min(lo + batch, len(data)))
        b = data.batch(idx, np.zeros(len(idx), int))
        terms = total_loss(forward(model, b), b, BASELINE)
        for k, v in terms.items():
            sums[k] = sums.get(k, 0.0) + float(v) * len(idx)
    model.train()
    return {k: v / len(data) for k, v in sums.items()}


def train_step(model: Student, opt: torch.optim.Optimizer, b: dict[str, torch.Tensor], weights: LossWeights,
               lr: float) -> dict[str, torch.Tensor]:
    """One optimizer step on batch b at learning rate lr; returns the loss terms."""
    for g in opt.param_groups:
        g["lr"] = lr
    terms = total_loss(forward(model, b), b, weights)
    opt.zero_grad(set_to_none=True)
    terms["loss"].backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), GRAD_CLIP)
    opt.step()
    return terms


def make_optimizer(model: Student) -> torch.optim.AdamW:
    decay = [p for p in model.parameters() if p.dim() >= 2]
    other = [p for p in model.parameters() if p.dim() < 2]
    return torch.optim.AdamW([{"params": decay, "weight_decay": WEIGHT_DECAY},
                              {"params": other, "weight_decay": 0.0}], lr=LR, betas=(0.9, 0.95))


def train(cfg: TrainConfig) -> Path:
    """Train one student; returns the model checkpoint file (``cfg.out/student.pt``).

    One function on purpose, as nanoGPT's train.py: the story (seed, data, model and
    optimizer, loop, save) reads top to bottom, its steps in small helpers above."""
    t0 = time.perf_counter()
    # seed: the network's initial weights come from torch's global generator,
    # seeded here (torch.nn layers take no generator); every other draw from rng below
    torch.manual_seed(cfg.seed)
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    # data
    cache_dir = Path(cfg.cache_dir) if cfg.cache_dir else Path(cfg.data) / "cache"
    teacher = None if cfg.teacher == "none" else cfg.teacher
    data = StudentData.load(cfg.data, cache_dir, VIEWS, teacher)
    val = StudentData.load(cfg.val, cache_dir, 1) if cfg.val else None
    # model and optimizer
    model = Student(cfg.net)
    model.train()
    opt = make_optimizer(model)
    weights = cfg.loss_weights
    plans = [epoch_plan(data, rng) for _ in range(cfg.epochs)]
    steps = [len(order) // BATCH for order, _, _ in plans]
    if min(steps) < 1:
        raise BadInput(f"{cfg.data} has {len(data)} frames, fewer than one batch of {BATCH} per epoch")
    total = sum(steps) if cfg.max_steps is None else min(cfg.max_steps, sum(steps))
    tqdm.write(f"student: {n_params(model):,} parameters; {len(data):,} frames, {total} steps of {BATCH}, "
               f"teacher {cfg.teacher}, seed {cfg.seed}")
    # loop
    step, history, t_loop, t_val = 0, [], time.perf_counter(), 0.0
    bar = tqdm(total=total, desc=f"train ({cfg.teacher})", unit="step", disable=None)
    for epoch, (order, views, cuts) in enumerate(plans):
        sums: dict[str, float] = {}
        steps_per_epoch = steps[epoch]
        for i in range(steps_per_epoch):
            if step >= total:
                break
            idx = order[i * BATCH:(i + 1) * BATCH]
            terms = train_step(model, opt, data.batch(idx, views[idx], cuts[idx]), weights, get_lr(step, total))
            for k, v in terms.items():
                sums[k] = sums.get(k, 0.0) + v.item()
            step += 1
            bar.update(1)
            bar.set_postfix(loss=f"{terms['loss'].item():.3f}", epoch=epoch + 1)
        n = max(1, min(steps_per_epoch, step - sum(steps[:epoch])))
        record = {"epoch": epoch + 1, "step": step, "train": {k: v / n for k, v in sums.items()}}
        if val is not None:
            tv = time.perf_counter()
            record["val"] = estimate_loss(model, val)
            t_val += time.perf_counter() - tv
        history.append(record)
        tqdm.write(_epoch_line(record))
        if step >= total:
            break
    bar.close()
    train_s = time.perf_counter() - t_loop - t_val
    # save
    manifest = {
        "data": str(cfg.data), "data_hash": data.digest, "val": str(cfg.val) if cfg.val else None,
        "val_hash": val.digest if val else None, "teacher": cfg.teacher, "seed": cfg.seed,
        "git_commit": git_commit(), "epochs": cfg.epochs, "steps": step, "batch": BATCH, "frames": len(data),
        "loss_weights": asdict(weights), "schedule": {"lr": LR, "min_lr": MIN_LR, "warmup_steps": WARMUP_STEPS,
                                                      "weight_decay": WEIGHT_DECAY, "aug_prob": AUG_PROB,
                                                      "keep_stay": KEEP_STAY, "cut_prob": CUT_PROB},
        "final_train": history[-1]["train"] if history else {}, "final_val": history[-1].get("val") if history else None,
        "history": history, "threads": cfg.threads, "train_samples_per_s": step * BATCH / max(train_s, 1e-9),
        "wall_s": time.perf_counter() - t0,
    }
    return save_checkpoint(Path(cfg.out) / WEIGHTS_NAME, model, manifest)


def _epoch_line(r: dict) -> str:
    line = f"epoch {r['epoch']}: train " + " ".join(f"{k} {v:.4f}" for k, v in r["train"].items())
    if "val" in r:
        line += " | val " + " ".join(f"{k} {v:.4f}" for k, v in r["val"].items())
    return line
