"""Training the student, top to bottom (docs/design.md §7).

    sumo-scimm train --data data/train --val data/val --teacher none  --out runs/student_baseline
    sumo-scimm train --data data/train --val data/val --teacher scimm --seed 1 --out runs/student_scimm
    sumo-scimm train --data data/train --val data/val --teacher control --teacher-weight 0.5 --out runs/ctl
    sumo-scimm train curves --runs baseline=runs/student_baseline scimm=runs/student_scimm --out curves.png

Story: seed -> data (cached BEVs, teacher files) -> model -> optimizer -> loop (pure
learning-rate schedule, validation loss averaged under no_grad after every epoch, the best
epoch kept) -> save the chosen epoch's weights.

Schedule (fixed, the same for every arm): AdamW (betas 0.9/0.95, weight decay 0.01 on
every tensor of two or more dimensions: weight matrices, kernels, the learned queries
and position embeddings), batch BATCH (``--batch``), learning rate linear warm-up over
WARMUP_STEPS to LR, then cosine decay to MIN_LR at the last step; gradient norm clipped to
1.0. With ``ema`` (``--ema``, off by default) an exponential moving average of the weights
(Ema) is what is validated, kept and saved (docs/student.md: it did not help on `val`). Samples
are drawn per epoch as the data balance below says, in a seeded random order; with
probability AUG_PROB a frame is seen from an augmented view (model.cache), with
probability CUT_PROB its route is cut ahead (model.data, route-end augmentation); a
repeated frame keeps its view and cut within the epoch.

Data balance: 38 % of the recorded frames show the expert standing and still standing 2.5 s
later (red lights, stop signs, queues), 6 % standing and then starting off. A student
without memory cannot tell "just arrived" from "waited long enough", learns to stay once
stopped and never starts again (in closed loop, a student with the speed input trained on
every frame stands 55-76 % of the time and moves only when the 40 s creep rule fires). So
each epoch draws:
- no standing-and-staying frame while the expert waits at a stop sign (a third of them):
  the BEV stops drawing the stop line once the stop is made (harness.sim.stop_signs), but
  the expert then still waits STOP_CLEAR and for cross traffic, and from one BEV that wait
  is ambiguous, while the frames that approach the sign (moving) teach the student to stop
  there and its starting-off frames (kept, below) to go once the line is gone. Kept as
  before the stop-line rule: keeping these frames is a setting to compare on `val`;
- KEEP_STAY of the other standing-and-staying frames (a new seeded subset every epoch);
- every starting-off frame (standing, moved >= 0.5 m 2.5 s later) DEPART_REPEAT times;
- every other frame once.

Teacher arms (``--teacher fixed|scimm|smoother``) add the teacher terms of eq. 11 and the mode term
of eq. 13 with model.loss.LossWeights (``weights``: ``--teacher-weight`` = l_scimm,
``--mode-weight`` = l_mode); ``--teacher control`` adds the same terms with the same
weights against the expert's own labels and a uniform mode target (model.data), so it
differs from a teacher arm only in the targets' content; ``--teacher none`` is the
baseline (l_scimm = l_mode = 0 whatever ``weights`` says) and never opens teacher files.
The validation loss is L_origin (expert path + speed waypoints, no augmentation) on the
validation dataset, the same for every arm.

Epochs and the chosen epoch: an epoch is EPOCH_STEPS optimizer steps (``--epoch-steps``)
drawn from a fresh balanced permutation (the draw above holds about 101k samples, 790
batches, on the 128k-frame training set, so an epoch sees about half of it; 0 = the whole
draw). The cosine schedule spans all ``epochs``; after every epoch the validation L_origin
is computed and the weights of the best epoch so far are kept in memory (a strictly lower
loss is a new best, so ties keep the earlier epoch). By default every arm runs the whole
schedule and the best epoch of it is saved: with early stopping (patience 3; software 0.2.0)
a baseline stopped at its 7th of 10 epochs and kept the 4th, because the validation speed-waypoint
loss jumps by about 15 % from epoch to epoch early in the schedule, while other arms ran
all 10; the arms then differed in training length. ``patience`` (``--patience``) still
stops a training after that many epochs without a new best. The manifest and
``history.json`` say which epoch was chosen, its validation loss and why the training
stopped (``stop_reason``: ``epochs``, all of them run; ``patience``; ``max_steps``, the
step budget ran out; ``no_val``, no validation set, so the last epoch is saved;
``no_finite_val``, the validation loss was never finite: the last epoch). Why the
criterion is this: it is the one loss every arm shares (L_origin on ``val``), it needs no
extra run per arm, and the evaluation routes never take part in it.

Schedule length (EPOCHS x EPOCH_STEPS = 3,200 steps, about 3.7 min for an SC-IMM student on
a 2-core Intel Xeon): set by docs/design.md §11's target for ``reproduce``, five
arms of a seed trained and evaluated in <= 75 min on 2 cores (``OUT/stages.json`` has the
stage times). Its cost on ``val`` (software 0.2.0, seed 0, students with the speed input, one
training each): best L_origin 1.896 (control) and 1.886 (SC-IMM) after 3,200 steps, against
1.732 and 1.673 after 10 epochs of whole draws (7,902 steps, about 15 min); docs/student.md,
"Training". Longer trainings: ``--epochs`` and ``--epoch-steps``. Cheaper ones tried on
`val` (batch 64; 2,000-2,400 steps, also at ``--lr 2e-3``) lost validation loss and `val`
DS on average, or were not shown to be no worse (docs/student.md, "Cost of one arm and
seed").

Determinism: torch.manual_seed(seed), deterministic algorithms, a fixed thread count, and
one numpy generator (seed) for sample order and views, drawn for every epoch up front (an
early stop does not change the draws of the epochs run): same seed, same data -> same
weights, and the same chosen epoch.
"""
from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from files.atomic import write_atomic
from harness.common.errors import BadInput
from harness.common.progress import progress
from harness.runs.provenance import machine
from model.checkpoint import HISTORY_NAME, WEIGHTS_NAME, git_commit, save_checkpoint
from model.data import TEACHERS, StudentData
from model.loss import BASELINE, LossWeights, total_loss
from model.network import NetConfig, Student, n_params

BATCH = 128
LR = 1e-3  # peak learning rate
MIN_LR = 2e-5  # at the last step of the last epoch (``epochs``)
WARMUP_STEPS = 200
WEIGHT_DECAY = 0.01
GRAD_CLIP = 1.0
AUG_PROB = 0.5  # share of samples seen from an augmented view
VIEWS = 2  # cached views per frame: as recorded + one augmented
KEEP_STAY = 0.15  # share of standing frames (StudentData.staying) drawn per epoch
DEPART_REPEAT = 3  # draws per epoch of a starting-off frame (StudentData.departing)
CUT_PROB = 0.1  # share of samples with the route cut ahead (route-end augmentation)
CUT_RANGE = (4.0, 30.0)  # [m] the cut distance, uniform
EPOCHS = 8  # the cosine schedule spans them; the best on `val` is saved
EPOCH_STEPS = 400  # optimizer steps per epoch (51,200 samples); 0 = the whole balanced draw
PATIENCE = None  # no early stop: every arm runs the whole schedule (the docstring says why)
EMA = 0.0  # decay of the weight average (Ema); 0 = none
THREADS = 2  # torch threads (fixed, so results do not depend on the machine's core count)
# torch's deterministic mode also fills every new tensor with NaN, so that a kernel reading
# memory it never wrote shows; the student's kernels read none (the weights are equal bit for
# bit with and without: tests/test_train.py), and the fills cost about 5 % of a one-thread step
FILL_UNINITIALIZED = False


@dataclass(frozen=True)
class TrainConfig:
    """One training (the options of ``sumo-scimm train``): teacher ``none`` (baseline, l_scimm =
    l_mode = 0 whatever ``weights`` says), ``control`` (the expert's own labels in the teacher
    terms) or a teacher method; ``weights`` = LossWeights(scimm=--teacher-weight,
    mode=--mode-weight); ``epochs`` x ``epoch_steps`` the schedule, ``patience`` an optional early stop."""

    data: Path
    out: Path
    teacher: str = "none"  # none | control | fixed | scimm | smoother
    val: Path | None = None  # validation dataset: its L_origin chooses the epoch saved
    seed: int = 0
    epochs: int = EPOCHS  # the cosine schedule spans them all
    epoch_steps: int = EPOCH_STEPS  # optimizer steps per epoch; 0 = the whole balanced draw
    patience: int | None = PATIENCE  # early stopping after this many epochs without a new best (``val`` only)
    cache_dir: Path | None = None  # default: <data>/cache (BEV cache, shared by trainings)
    max_steps: int | None = None  # stop early (tests, benchmarks); None = all epochs
    threads: int = THREADS
    batch: int = BATCH  # samples per optimizer step
    ema: float = EMA  # decay of the weight average validated and saved; 0 = the raw weights
    lr: float = LR  # peak learning rate
    net: NetConfig = field(default_factory=NetConfig)
    weights: LossWeights = field(default_factory=LossWeights)  # eq. 10; ignored for teacher none

    def __post_init__(self) -> None:
        if self.teacher not in ("none", *TEACHERS):
            raise BadInput(f"--teacher must be none, {', '.join(TEACHERS)}, got {self.teacher!r}")
        if self.epochs < 1:
            raise BadInput(f"--epochs must be >= 1, got {self.epochs}")
        if self.epoch_steps < 0:
            raise BadInput(f"--epoch-steps must be >= 0 (0 = the whole balanced draw), got {self.epoch_steps}")
        if self.patience is not None and self.patience < 1:
            raise BadInput(f"--patience must be >= 1, got {self.patience}")
        if self.seed < 0:
            raise BadInput(f"--seed must be >= 0, got {self.seed}")
        if self.threads < 1:
            raise BadInput(f"--threads must be >= 1, got {self.threads}")
        if self.batch < 1:
            raise BadInput(f"--batch must be >= 1, got {self.batch}")
        if not 0.0 <= self.ema < 1.0:
            raise BadInput(f"--ema must be in [0, 1), got {self.ema}")
        if not MIN_LR < self.lr < 1.0:
            raise BadInput(f"--lr must be in ({MIN_LR:g}, 1), got {self.lr}")

    @property
    def loss_weights(self) -> LossWeights:
        return BASELINE if self.teacher == "none" else self.weights

    @property
    def cache(self) -> Path:
        """The BEV cache folder: ``cache_dir``, else <data>/cache."""
        return Path(self.cache_dir) if self.cache_dir else Path(self.data) / "cache"


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


def get_lr(step: int, total: int, peak: float = LR) -> float:
    """Learning rate at optimizer step ``step`` of ``total``, peaking at ``peak``."""
    if step < WARMUP_STEPS:  # 1) linear warm-up
        return peak * (step + 1) / WARMUP_STEPS
    if step >= total - 1:  # 2) the end of the schedule
        return MIN_LR
    ratio = (step - WARMUP_STEPS) / max(1, total - 1 - WARMUP_STEPS)  # 3) cosine decay to MIN_LR
    return MIN_LR + 0.5 * (1.0 + math.cos(math.pi * ratio)) * (peak - MIN_LR)


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


class Best:
    """The best epoch so far: the epoch with the lowest validation L_origin so far
    (``val["loss"]`` of estimate_loss, path + speed waypoints [m^2]) and a copy of its weights."""

    def __init__(self) -> None:
        self.epoch, self.val, self.state = 0, math.inf, None

    def update(self, model: Student, record: dict) -> None:
        """Keep ``model``'s weights if the epoch of ``record`` beats the best so far."""
        if record["val"]["loss"] < self.val:
            self.epoch, self.val = record["epoch"], record["val"]["loss"]
            self.state = {k: v.detach().clone() for k, v in model.state_dict().items()}

    def waited(self, epoch: int) -> int:
        """Epochs since the best one, at the end of ``epoch``."""
        return epoch - self.epoch


class Ema:
    """An exponential moving average of the weights (Polyak averaging): after optimizer step t
    (from 0), avg = d avg + (1 - d) w with d = min(decay, (1 + t) / (10 + t)), so the initial
    weights fade fast (a tenth of the average after step 0). The warm-up holds d below
    ``decay`` until step (10 decay - 1) / (1 - decay): 4,490 for 0.998, so over the default
    3,200 steps such a decay only rises to 0.997. The average is what is validated and saved."""

    def __init__(self, model: Student, decay: float) -> None:
        self.decay, self.t = decay, 0
        self.model = copy.deepcopy(model)
        self.model.requires_grad_(False)

    @torch.no_grad()
    def update(self, model: Student) -> None:
        d = min(self.decay, (1 + self.t) / (10 + self.t))
        torch._foreach_lerp_(list(self.model.parameters()), list(model.parameters()), 1.0 - d)
        self.t += 1


def run_epoch(model: Student, opt: torch.optim.Optimizer, data: StudentData,
              plan: tuple[np.ndarray, np.ndarray, np.ndarray], n_steps: int, cfg: TrainConfig,
              step: int, total: int, bar: tqdm, ema: Ema | None = None,
              on_step: Callable[[], None] | None = None) -> tuple[dict, int]:
    """Up to ``n_steps`` optimizer steps of ``cfg.batch`` samples over one epoch's plan
    (stopping at ``total``), each followed by the weight average's update and ``on_step()``;
    returns (mean train loss terms, step after the epoch)."""
    order, views, cuts = plan
    batch, weights = cfg.batch, cfg.loss_weights
    sums: dict[str, float] = {}
    n = 0
    for i in range(n_steps):
        if step >= total:
            break
        idx = order[i * batch:(i + 1) * batch]
        terms = train_step(model, opt, data.batch(idx, views[idx], cuts[idx]), weights, get_lr(step, total, cfg.lr))
        if ema is not None:
            ema.update(model)
        for k, v in terms.items():
            sums[k] = sums.get(k, 0.0) + v.item()
        step, n = step + 1, n + 1
        bar.update(1)
        bar.set_postfix(loss=f"{terms['loss'].item():.3f}", refresh=False)  # drawn with the next update
        if on_step is not None:
            on_step()
    return {k: v / max(1, n) for k, v in sums.items()}, step


def train(cfg: TrainConfig, on_step: Callable[[], None] | None = None) -> Path:
    """Train one student; returns the model checkpoint file (``cfg.out/student.pt``).
    ``on_step()`` after every optimizer step (model.side_by_side counts steps with it).

    One function on purpose, as nanoGPT's train.py: the story (seed, data, model and
    optimizer, loop with the best epoch kept, save) reads top to bottom, its steps in small
    helpers above."""
    t0 = time.perf_counter()
    # seed: the network's initial weights come from torch's global generator,
    # seeded here (torch.nn layers take no generator); every other draw from rng below
    torch.manual_seed(cfg.seed)
    torch.use_deterministic_algorithms(True)
    torch.utils.deterministic.fill_uninitialized_memory = FILL_UNINITIALIZED
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    # data
    cache_dir = cfg.cache
    teacher = None if cfg.teacher == "none" else cfg.teacher
    data = StudentData.load(cfg.data, cache_dir, VIEWS, teacher)
    val = StudentData.load(cfg.val, cache_dir, 1) if cfg.val else None
    # model and optimizer
    model = Student(cfg.net)
    model.train()
    opt = make_optimizer(model)
    weights = cfg.loss_weights
    ema = Ema(model, cfg.ema) if cfg.ema else None
    validated = ema.model if ema else model  # the weights validated, kept and saved
    plans = [epoch_plan(data, rng) for _ in range(cfg.epochs)]
    steps = [len(order) // cfg.batch for order, _, _ in plans]  # whole batches of each epoch's draw
    steps = [min(n, cfg.epoch_steps) for n in steps] if cfg.epoch_steps else steps
    if min(steps) < 1:
        raise BadInput(f"{cfg.data} has {len(data)} frames, fewer than one batch of {cfg.batch} per epoch")
    total = sum(steps) if cfg.max_steps is None else min(cfg.max_steps, sum(steps))
    tqdm.write(f"student: {n_params(model):,} parameters; {len(data):,} frames, at most {total} steps of {cfg.batch}, "
               f"teacher {cfg.teacher}, seed {cfg.seed}")
    # loop: one epoch, its validation loss, the best epoch kept (an early stop with patience)
    step, history, best, stop = 0, [], Best(), "epochs"
    bar = progress(total=total, desc=f"train ({cfg.teacher})", unit="step")
    for epoch, plan in enumerate(plans, start=1):
        te = time.perf_counter()
        bar.set_description(f"train ({cfg.teacher}) epoch {epoch}/{cfg.epochs}", refresh=False)
        means, step = run_epoch(model, opt, data, plan, steps[epoch - 1], cfg, step, total, bar, ema, on_step)
        record = {"epoch": epoch, "step": step, "lr": get_lr(step - 1, total, cfg.lr), "train": means,
                  "seconds": round(time.perf_counter() - te, 3)}
        if val is not None:
            tv = time.perf_counter()
            record["val"] = estimate_loss(validated, val)
            record["val_seconds"] = round(time.perf_counter() - tv, 3)
            best.update(validated, record)
        history.append(record)
        tqdm.write(_epoch_line(record))
        if val is not None and cfg.patience is not None and best.waited(epoch) >= cfg.patience:
            stop = "patience"
            break
        if step >= total:
            stop = "max_steps" if total < sum(steps) else "epochs"
            break
    bar.close()
    # the chosen epoch: the best on val (its weights back in the model), else the last
    if val is None or best.state is None:  # no validation set, or no finite validation loss (diverged)
        stop, chosen = "no_val" if val is None else "no_finite_val", history[-1]
        model.load_state_dict(validated.state_dict())
    else:
        model.load_state_dict(best.state)
        chosen = history[best.epoch - 1]
    tqdm.write(f"chosen epoch {chosen['epoch']} of {len(history)} (stop: {stop})")
    # save: history.json first, so a checkpoint file always has its history beside it
    manifest = _manifest(cfg, data, val, weights, history, chosen, stop, time.perf_counter() - t0)
    Path(cfg.out).mkdir(parents=True, exist_ok=True)
    write_atomic(Path(cfg.out) / HISTORY_NAME, json.dumps({k: manifest[k] for k in HISTORY_KEYS}, indent=1) + "\n")
    return save_checkpoint(Path(cfg.out) / WEIGHTS_NAME, model, manifest)


HISTORY_KEYS = ("teacher", "seed", "loss_weights", "chosen_epoch", "chosen_val", "stop_reason", "history")


def _manifest(cfg: TrainConfig, data: StudentData, val: StudentData | None, weights: LossWeights,
              history: list[dict], chosen: dict, stop: str, wall_s: float) -> dict:
    """What the checkpoint says of its training (``final_*``: the last epoch run; ``chosen_*``:
    the epoch whose weights are saved)."""
    train_s = sum(r["seconds"] for r in history)
    return {
        "data": str(cfg.data), "data_hash": data.digest, "val": str(cfg.val) if cfg.val else None,
        "val_hash": val.digest if val else None, "teacher": cfg.teacher, "seed": cfg.seed,
        "git_commit": git_commit(), "net": cfg.net.to_dict(),
        "epochs": cfg.epochs, "epoch_steps": cfg.epoch_steps,
        "patience": cfg.patience, "epochs_run": len(history),
        "steps": history[-1]["step"], "batch": cfg.batch, "ema": cfg.ema, "frames": len(data),
        "loss_weights": asdict(weights),
        "schedule": {"lr": cfg.lr, "min_lr": MIN_LR, "warmup_steps": WARMUP_STEPS, "weight_decay": WEIGHT_DECAY,
                     "aug_prob": AUG_PROB, "keep_stay": KEEP_STAY, "cut_prob": CUT_PROB},
        "final_train": history[-1]["train"], "final_val": history[-1].get("val"),
        "chosen_epoch": chosen["epoch"], "chosen_val": chosen.get("val"), "stop_reason": stop,
        "history": history, "threads": cfg.threads, "machine": machine(),
        "train_samples_per_s": history[-1]["step"] * cfg.batch / max(train_s, 1e-9), "wall_s": wall_s,
    }


def _epoch_line(r: dict) -> str:
    line = f"epoch {r['epoch']}: train " + " ".join(f"{k} {v:.4f}" for k, v in r["train"].items())
    if "val" in r:
        line += " | val " + " ".join(f"{k} {v:.4f}" for k, v in r["val"].items())
    return line
