"""Several students trained at once: spawned processes, one torch thread each.

    train_side_by_side([cfg_a, cfg_b, cfg_c], processes=2)  # -> [a/student.pt, b/..., c/...]

Why: a training step of the student is a few hundred small operations (convolutions on a
64 x 64 BEV, attention over 64 tokens of width 64, batch 128), which two threads share
badly: two trainings with one thread each, side by side on 2 cores, finish in 0.78-0.82 x
the time of the same two one after the other on two threads (an SC-IMM and a Fixed-IMM
student of 800 steps each, data loading and validation included: 117.8 s against 150.9 s,
118.3 s against 144.2 s; 2-core Intel Xeon). ``sumo-scimm reproduce`` trains its students
so (docs/student.md, "Cost of one arm and seed").

Each training runs ``model.train.train`` unchanged with ``threads`` = 1, and a training
is deterministic at a given thread count, so a student trained here has the weights that
``sumo-scimm train ... --threads 1`` gives alone (its manifest records ``threads``).
The BEV caches the trainings read are rendered first, in the calling process, once each.
A training's own output (epoch lines, and a progress line at most every 30 s:
harness.common.progress) goes to ``train.log`` in its output folder; the
parent shows one progress bar over every training's steps. A training that fails raises
its error here once the others have finished; a stop (Ctrl-C, SIGTERM) ends every training.
"""
from __future__ import annotations

import multiprocessing as mp
import signal
import sys
import traceback
from dataclasses import replace
from pathlib import Path
from time import sleep

from harness.common.progress import progress
from model.train import TrainConfig

SIDE_BY_SIDE = 2  # trainings at once (one per core of a 2-core machine)
THREADS_EACH = 1  # torch threads of each
LOG_NAME = "train.log"  # a training's own output, in its output folder
_steps = None  # the shared step counts (one slot per training), in a training process
_slot = -1  # the slot of the training this process runs


def train_side_by_side(cfgs: list[TrainConfig], processes: int = SIDE_BY_SIDE) -> list[Path]:
    """Train every config (with ``threads`` = THREADS_EACH), ``processes`` at a time, each
    in its own spawned process; returns the checkpoint files in the order of ``cfgs``."""
    if not cfgs:
        return []
    cfgs = [replace(c, threads=THREADS_EACH) for c in cfgs]
    _build_caches(cfgs)
    for c in cfgs:
        Path(c.out).mkdir(parents=True, exist_ok=True)
    ctx = mp.get_context("spawn")
    # one count per training, each written by its own training only: no lock is needed, and
    # a lock would be a named semaphore that Python's resource tracker may report as leaked
    # when the pool's processes end
    steps = ctx.RawArray("q", len(cfgs))
    total = sum(min(c.epochs * c.epoch_steps, c.max_steps or c.epochs * c.epoch_steps) for c in cfgs) \
        if all(c.epoch_steps for c in cfgs) else None  # 0 = the whole draw: not known before loading
    bar = progress(total=total, desc=f"train {len(cfgs)} students, {processes} at a time", unit="step")
    pool = ctx.Pool(min(processes, len(cfgs)), initializer=_init, initargs=(steps,))
    try:
        pending = [pool.apply_async(_train_one, (i, c)) for i, c in enumerate(cfgs)]
        while not all(p.ready() for p in pending):
            sleep(0.5)
            bar.update(sum(steps) - bar.n)
        bar.update(sum(steps) - bar.n)
        bar.close()
    except BaseException:  # a stop (Ctrl-C, SIGTERM): end the trainings now
        pool.terminate()
        pool.join()
        raise
    pool.close()  # every training has ended: the processes exit on their own
    pool.join()
    return [p.get() for p in pending]  # the first failure raised, in the order of cfgs


def _build_caches(cfgs: list[TrainConfig]) -> None:
    """The BEV caches of the trainings' datasets, rendered here first, once each: trainings
    side by side would render a shared cache twice, and a pool's process cannot start
    render processes of its own."""
    from model.cache import build_cache
    from model.data import check_dataset
    from model.train import VIEWS
    done = set()
    for c in cfgs:
        for folder, views in [(c.data, VIEWS)] + ([(c.val, 1)] if c.val else []):
            if (key := (str(folder), str(c.cache), views)) not in done:
                check_dataset(Path(folder))
                build_cache(Path(folder), c.cache, views)
                done.add(key)


def _init(steps) -> None:
    global _steps
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which ends the pool
    _steps = steps


def _count_step() -> None:
    _steps[_slot] += 1


def _train_one(slot: int, cfg: TrainConfig) -> Path:
    global _slot
    from model.train import train
    _slot = slot
    with open(Path(cfg.out) / LOG_NAME, "w", buffering=1) as log:  # line by line, to follow it
        sys.stdout = sys.stderr = log  # epoch lines, and a progress line at most every 30 s (a log)
        try:
            return train(cfg, on_step=_count_step)
        except BaseException:
            traceback.print_exc()  # into the log; the parent raises the error itself
            raise
        finally:
            sys.stdout, sys.stderr = sys.__stdout__, sys.__stderr__
