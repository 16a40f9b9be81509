"""Student figures for ``sumo-scimm bench`` (docs/design.md §11): training samples/s, inference ms/frame.

Both run the real code paths on synthetic inputs (random BEV bits, labels and teacher
labels), so they measure the network, the loss and the batch assembly, not a dataset:

- training: ``model.train.train_step`` with the full SC-IMM loss at batch 128 on
  ``model.train.THREADS`` threads, batches unpacked from bit-packed BEVs as in training;
  samples/s over ``train_steps`` steps after ``warmup`` steps (reference: >= 500);
- inference: one network call of ``StudentAgent`` (binarise, ``infer``: network, numpy out)
  at batch 1 on one thread, mean over ``infer_frames`` calls (reference: <= 3 ms).

Wall-clock figures are the ones compared with the references; the process CPU-time
figures beside them (samples per CPU second, CPU ms per frame) show what the code costs
when the machine is shared (on an idle 2-core machine, wall samples/s approaches up to
2x the per-CPU-second figure).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from model import cache as bevcache
from model.agent import INFERENCE_THREADS, StudentAgent
from model.data import StudentData
from model.loss import LossWeights
from model.network import NetConfig, Student
from model.train import BATCH, THREADS, make_optimizer, train_step

TRAIN_REF = 500.0  # samples/s (docs/design.md §11)
INFER_REF = 3.0  # ms per frame (docs/design.md §11)


def synthetic_data(n: int, rng: np.random.Generator) -> StudentData:
    """n frames of random inputs and labels, one augmented view, with teacher labels."""
    views = 2
    bev = (rng.random((n, views, *bevcache.BEV_SHAPE)) < 0.15).astype(np.uint8) * 255
    arrays = {"bev": bevcache.pack(bev), "aug": rng.uniform(-0.5, 0.5, (n, views, 2)),
              "path": rng.normal(size=(n, views, 20, 2)).astype(np.float32),
              "speed_wps": rng.normal(size=(n, views, 10, 2)).astype(np.float32),
              "target_point": rng.normal(size=(n, views, 2)).astype(np.float32),
              "speed": rng.uniform(0, 10, n).astype(np.float32)}
    teacher = {"path": rng.normal(size=(n, 20, 2)).astype(np.float32),
               "speed": rng.uniform(0, 10, (n, 10)).astype(np.float32),
               "mu": rng.dirichlet(np.ones(5), n).astype(np.float32)}
    return StudentData(arrays, teacher, "synthetic", Path("."))


def run_student_bench(train_steps: int = 20, warmup: int = 3, infer_frames: int = 300, seed: int = 0) -> dict:
    """{"train_samples_per_s", "infer_ms_per_frame"} and their references."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    threads_before = torch.get_num_threads()
    try:
        torch.set_num_threads(THREADS)
        data = synthetic_data(BATCH * 4, rng)
        model = Student(NetConfig())
        model.train()
        opt = make_optimizer(model)
        t = cpu = 0.0
        for i in range(warmup + train_steps):
            idx = rng.integers(0, len(data), BATCH)
            t0, c0 = time.perf_counter(), time.process_time()
            train_step(model, opt, data.batch(idx, rng.integers(0, 2, BATCH)), LossWeights(), 1e-4)
            if i >= warmup:
                t, cpu = t + time.perf_counter() - t0, cpu + time.process_time() - c0

        torch.set_num_threads(INFERENCE_THREADS)
        agent = StudentAgent()
        agent.use(model)
        bev = (rng.random(bevcache.BEV_SHAPE) < 0.15).astype(np.uint8) * 255
        for _ in range(10):
            agent.infer(bevcache.binarize(bev), np.array([10.0, 1.0]), 5.0)
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(infer_frames):  # the network call of every tick whose inputs are new
            agent.infer(bevcache.binarize(bev), np.array([10.0, 1.0]), 5.0)
        infer_ms = (time.perf_counter() - t0) / infer_frames * 1000.0
        infer_cpu_ms = (time.process_time() - c0) / infer_frames * 1000.0
    finally:
        torch.set_num_threads(threads_before)
    n = train_steps * BATCH
    return {"train_samples_per_s": n / t, "train_samples_per_cpu_s": n / cpu, "train_ref": TRAIN_REF,
            "infer_ms_per_frame": infer_ms, "infer_cpu_ms_per_frame": infer_cpu_ms, "infer_ref": INFER_REF}


def format_student_bench(r: dict) -> str:
    return (f"student training      {r['train_samples_per_s']:8.0f} samples/s  (ref >= {r['train_ref']:.0f}; "
            f"{r['train_samples_per_cpu_s']:.0f} per CPU second)\n"
            f"student inference     {r['infer_ms_per_frame']:8.2f} ms/frame   (ref <= {r['infer_ref']:.0f}; "
            f"{r['infer_cpu_ms_per_frame']:.2f} CPU ms)")
