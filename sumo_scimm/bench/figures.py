"""The figures of ``sumo-scimm bench`` that span stages: every performance figure of
docs/design.md §11, each beside its reference measured in the same run (the command in
sumo_scimm.bench.command prints them as a table and optionally writes them as JSON).

- closed loop (``closed_loop``): harness step with the chosen agent against bare libsumo
  stepping of the same traffic with the ego replayed, plus, for a student, its bare
  inference (its own checkpoint's ``infer`` after ``binarize``, what ``predict`` runs on a new
  input, on inputs recorded in the same episodes, one
  thread), and, for reading, the libsumo replay with that network run between steps and
  the ratio's floor (SUMO and the network alternating, nothing else); BEV render;
- teacher (``imm``): batched IMM frames per second on one core against filterpy's
  IMMEstimator on the same sequences, and the largest difference between them;
- student (``student``): training samples per second on 2 threads, inference ms per
  frame at batch 1 on one thread;
- collect (``closed_loop.collect_rate``): simulated seconds per wall second of one worker
  recording the expert as ``sumo-scimm collect`` does;
- with ``--eval``: wall time of a whole ``town12_short`` evaluation on 2 workers with the
  agent, and the worker memory (RSS) over it;
- with ``--arm DIR``: one arm and seed of the experiment, run now as ``reproduce`` runs
  it: the SC-IMM and Fixed-IMM students of seed 0 trained side by side with the default
  recipe on the data of a ``reproduce`` output DIR, then each evaluated on
  ``town12_short`` on ``--workers``, the wall time over the two (target <= 5 min); then,
  untimed, the SC-IMM student's validation L_origin and ``val`` DS beside those of DIR's
  own seed-0 SC-IMM student.

The closed-loop figures and the IMM's are the median of ``--rounds`` passes (fresh
processes for the IMM), every pass printed and written beside it.

The run prints and writes the machine it ran on (CPU model, cores, torch's kernels,
versions). Figures are for reading, never asserted in a test; they depend on the machine
and its load.
"""
from __future__ import annotations

import itertools
import json
import re
import tempfile
import time
from pathlib import Path

EVAL_TARGET_S, OVERHEAD_TARGET, RSS_TARGET_MB = 180.0, 2.0, 800.0
# reproduce per seed: collect, teachers, every arm's training and evaluation, tables [s]
REPRODUCE_TARGET_S = {3: 3600.0, 5: 4500.0}  # up to 3 arms: 60 min; up to 5: 75 min
ARM_SEED_TARGET_S = 300.0  # one arm and seed: training plus the town12_short evaluation [s]


def eval_figures(agent: str, agent_config: str | None, workers: int, routes: str = "town12_short",
                 repetitions: int = 1, vehicle: str = "carla") -> dict:
    """Wall time and worker memory of ``sumo-scimm eval`` on ``routes`` (``repetitions``
    passes) with ``workers`` workers and ego model ``vehicle``, in a temporary run folder."""
    from harness.runs.evaluate import Backend, evaluate
    with tempfile.TemporaryDirectory(prefix="sumo-scimm-bench-") as tmp:
        t0 = time.perf_counter()
        res = evaluate(routes, agent, agent_config, Path(tmp) / "run", repetitions=repetitions,
                       backend=Backend(workers), vehicle=vehicle)
        wall = time.perf_counter() - t0
        return {"eval_wall_s": round(wall, 1), "eval_workers": workers, "eval_target_s": EVAL_TARGET_S,
                "rss": res.memory, "rss_target_mb": RSS_TARGET_MB, "routes": routes, "repetitions": repetitions,
                "route_runs": len(res.records), "vehicle": vehicle}


def check_arm_folder(folder: str) -> Path:
    """FOLDER/data of a ``reproduce`` output, if it holds the training and validation sets."""
    from harness.common.errors import BadInput
    data = Path(folder) / "data"
    if not (data / "train").is_dir() or not (data / "val").is_dir():
        raise BadInput(f"--arm {folder}: no data/train and data/val in it; give the --out folder of a "
                       f"'sumo-scimm reproduce' run")
    return data


def arm_seed_figure(folder: str, workers: int, vehicle: str = "carla", arms: tuple[str, ...] = ("scimm", "fixed"),
                    seed: int = 0, routes: str = "town12_short", val_routes: str = "val") -> dict:
    """Wall time of one arm and seed as ``reproduce`` runs it, now: the students of ``arms``
    of ``seed`` trained side by side with the default recipe (model.side_by_side, one
    thread each) on FOLDER/data/train (validation FOLDER/data/val, BEV cache
    FOLDER/data/cache, built first if missing and not timed), then each evaluated on
    ``routes`` on ``workers`` workers; all in a temporary folder. The figure is the whole
    wall time over the number of students.

    Then, not timed, the first arm's quality beside the student FOLDER/models/<arm>_s<seed>
    that the ``reproduce`` run trained (if present): the validation L_origin of each (from
    their histories) and the driving score of each on ``val_routes``."""
    from harness.runs.evaluate import Backend, evaluate
    from model.cache import build_cache
    from model.reproduce import ARMS
    from model.side_by_side import SIDE_BY_SIDE, train_side_by_side
    from model.train import VIEWS, TrainConfig
    data = check_arm_folder(folder)
    build_cache(data / "train", data / "cache", VIEWS, workers)  # the shared BEV cache, as reproduce has it
    build_cache(data / "val", data / "cache", 1, workers)

    def val_ds(ckpt: Path, out: Path) -> float:
        res = evaluate(val_routes, "student", str(ckpt), out, seed=seed, backend=Backend(workers), vehicle=vehicle)
        return res.global_record["scores_mean"]["score_composed"]

    with tempfile.TemporaryDirectory(prefix="sumo-scimm-bench-") as tmp:
        cfgs = [TrainConfig(data=data / "train", out=Path(tmp) / arm, teacher=dict(ARMS)[arm], val=data / "val",
                            seed=seed, cache_dir=data / "cache") for arm in arms]
        t0 = time.perf_counter()
        ckpts = train_side_by_side(cfgs)
        t_train = time.perf_counter() - t0
        history = json.loads((Path(tmp) / arms[0] / "history.json").read_text())
        t_eval = []
        for arm, ckpt in zip(arms, ckpts):
            t0 = time.perf_counter()
            evaluate(routes, "student", str(ckpt), Path(tmp) / f"run_{arm}", seed=seed, backend=Backend(workers),
                     vehicle=vehicle)
            t_eval.append(round(time.perf_counter() - t0, 1))
        r = {"arm": arms[0], "arms": list(arms), "seed": seed, "arm_train_s": round(t_train, 1),
             "arm_side_by_side": SIDE_BY_SIDE, "arm_eval_s": t_eval,
             "arm_seed_s": round((t_train + sum(t_eval)) / len(arms), 1), "arm_routes": routes, "arm_workers": workers,
             "arm_seed_target_s": ARM_SEED_TARGET_S, "arm_steps": history["history"][-1]["step"],
             "arm_batch": cfgs[0].batch, "arm_chosen_epoch": history["chosen_epoch"],
             "arm_val_loss": _chosen_loss(history), "arm_val_ds": val_ds(ckpts[0], Path(tmp) / "val")}
        before = Path(folder) / "models" / f"{arms[0]}_s{seed}"
        if (before / "student.pt").is_file() and (before / "history.json").is_file():
            old = json.loads((before / "history.json").read_text())
            r.update(before=str(before), before_val_loss=_chosen_loss(old),
                     before_val_ds=val_ds(before / "student.pt", Path(tmp) / "val_before"))
    return r


def _chosen_loss(history: dict) -> float:
    """The validation L_origin of the epoch a training kept (NaN when it had none finite)."""
    return (history.get("chosen_val") or {}).get("loss", float("nan"))


def reproduce_figure(folder: str) -> dict:
    """The stage wall times a finished ``sumo-scimm reproduce`` recorded in FOLDER/stages.json
    (measured when it ran, not now: reproduce takes about an hour)."""
    from harness.common.errors import BadInput
    from model.arm_tables import train_seconds
    path = Path(folder) / "stages.json"
    try:
        times = json.loads(path.read_text())
        total = float(sum(times.values()))
    except (OSError, ValueError, TypeError, AttributeError) as exc:
        raise BadInput(f"--reproduce {folder}: no readable stages.json of 'sumo-scimm reproduce' ({exc})") from None
    # "scimm s0" -> its training (or its share of a stage side by side) + its evaluation on the
    # main set [s], for every arm and seed with a training (an expert's evaluation has none)
    keys = dict.fromkeys((m[1], int(m[2])) for name in times
                         if (m := re.fullmatch(r"(?:train|eval) (\S+) s(\d+)", name)) and m[1] != "expert")
    arm_seeds = {f"{arm} s{seed}": t + times.get(f"eval {arm} s{seed}", 0.0)
                 for arm, seed in keys if (t := train_seconds(times, arm, seed)) is not None}
    # per seed: the run's whole time over its seeds (collect and teachers, done once, shared)
    seeds, arms = {seed for _, seed in keys}, {arm for arm, _ in keys}
    target = next((v for n, v in sorted(REPRODUCE_TARGET_S.items()) if len(arms) <= n), None)
    return {"reproduce_dir": str(folder), "reproduce_wall_s": round(total, 1), "stages": len(times),
            "seeds": len(seeds), "arms": len(arms),
            "reproduce_seed_s": round(total / max(len(seeds), 1), 1), "reproduce_target_s": target,
            "reproduce_arm_seed_s": {k: round(v, 1) for k, v in arm_seeds.items()}}


def machine() -> dict:
    """What the figures were measured on: CPU model, its family/model/stepping and widest
    vector extension, cores (harness.runs.provenance.machine), the kernels torch picked,
    and the versions that set the per-tick cost (torch trains the student, ONNX Runtime
    runs it in the closed loop). Figures of two runs compare only on the same kind of
    machine (and a student's records only on the same CPU type: docs/reliability.md)."""
    import importlib.metadata
    import platform

    import torch
    from harness.runs import provenance
    return {**provenance.machine(), "torch": torch.__version__,
            "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "onnxruntime": importlib.metadata.version("onnxruntime"),  # the student's runtime (model.runtime)
            "libsumo": importlib.metadata.version("libsumo"), "numpy": importlib.metadata.version("numpy"),
            "python": platform.python_version()}


def bare_inference(agent_name: str, agent_config: str | None):
    """For a student agent: (a function timing its own network call (binarised BEV, target
    point, speed in; path and speed waypoints out: ``infer`` after ``binarize``, what
    ``predict`` runs on a tick whose inputs are new) on recorded sensor inputs, with its
    checkpoint and thread setting, ms per call; a function giving a call that runs that
    network once on the next of such inputs, for ``run_bench``'s ``network_between``);
    else (None, None)."""
    from harness.loop.agent import load_agent
    from model.agent import StudentAgent
    from model.cache import binarize
    agent = load_agent(agent_name)
    if not isinstance(agent, StudentAgent):
        return None, None

    def network_between(inputs: list[dict]):
        agent.setup(agent_config)  # the checkpoint, in ONNX Runtime on INFERENCE_THREADS threads
        frames = [(d["bev"], d["target_point"], float(d["speed"])) for d in inputs]
        calls = itertools.count()

        def call():  # what infer_ms times: binarise, then the network
            bev, tp, speed = frames[next(calls) % len(frames)]
            agent.infer(binarize(bev), tp, speed)
        return call

    def infer_ms(inputs: list[dict], calls: int = 500, warmup: int = 20) -> float:
        agent.setup(agent_config)
        frames = [(d["bev"], d["target_point"], float(d["speed"])) for d in inputs]
        for i in range(warmup):
            bev, tp, speed = frames[i % len(frames)]
            agent.infer(binarize(bev), tp, speed)
        t0 = time.perf_counter()
        for i in range(calls):
            bev, tp, speed = frames[i % len(frames)]
            agent.infer(binarize(bev), tp, speed)
        return 1000 * (time.perf_counter() - t0) / calls
    return infer_ms, network_between
