"""The evaluation runner: routes fan out over worker processes, one libsumo each (SPEC §10).

Outputs in the run folder:

    records.jsonl   one JSON record per route run, appended and flushed as each ends
    records.csv     the same as a table, rewritten (atomically) after every route
    logs/<route>_rep<k>.npz   the per-tick event log of that run (harness.episode.EpisodeLog)

Every route run gets its own seed, derived from the run seed and the run's index in the
job list, so records do not depend on the number of workers. A worker that dies (kill -9,
segfault) has its route recorded as "Failed - Simulation crashed" with the reason; a new
worker takes over and the run goes on. ``resume`` keeps the complete records already in
``records.jsonl`` and runs only the rest (a torn last line is dropped and redone).
"""
from __future__ import annotations

import csv
import json
import multiprocessing as mp
import os
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path

import numpy as np
from tqdm import tqdm

from harness import criteria
from scenarios.routefile import Route

RECORD_FIELDS = ("key", "route_id", "repetition", "town", "status", "rc", "game_time", "wall_time",
                 "steps", "length", "km_driven", "seed", "message")


@dataclass(frozen=True)
class Job:
    index: int
    route: Route
    repetition: int
    agent: str
    agent_config: str | None
    seed: int
    log_dir: str

    @property
    def key(self) -> str:
        return f"{self.route.id}_rep{self.repetition}"


def route_seed(run_seed: int, index: int) -> int:
    """Seed of job ``index`` of a run: independent of worker count and order."""
    return int(np.random.SeedSequence([run_seed, index]).generate_state(1)[0])


def run_job(job: Job) -> dict:
    """Drive one route and save its log; returns the route record (runs in a worker)."""
    from harness.episode import run_episode
    res = run_episode(job.route, job.agent, job.agent_config, job.seed)
    log_path = Path(job.log_dir) / f"{job.key}.npz"
    tmp = log_path.with_name(log_path.name + ".tmp.npz")
    np.savez_compressed(tmp, **res.log.arrays())
    os.replace(tmp, log_path)
    length = round(res.length, 3)
    return {"key": job.key, "route_id": job.route.id, "repetition": job.repetition, "town": job.route.town,
            "status": res.status, "rc": res.rc, "game_time": res.game_time,
            "wall_time": round(res.wall_time, 3), "steps": res.steps, "length": length,
            "km_driven": round(length / 1000 * res.rc / 100, 6), "seed": job.seed, "message": res.message}


def _crash_record(job: Job, reason: str) -> dict:
    return {"key": job.key, "route_id": job.route.id, "repetition": job.repetition, "town": job.route.town,
            "status": criteria.FAILED_SIMULATION, "rc": 0.0, "game_time": 0.0, "wall_time": 0.0, "steps": 0,
            "length": round(float(job.route.length), 3), "km_driven": 0.0, "seed": job.seed, "message": reason}


def _worker(conn) -> None:
    while True:
        job = conn.recv()
        if job is None:
            return
        conn.send(run_job(job))


def read_records(path: Path) -> list[dict]:
    """Complete records of a records.jsonl (a torn last line is ignored)."""
    out = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict) and "key" in rec:
                out.append(rec)
    return out


def write_csv(records: list[dict], path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=RECORD_FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in sorted(records, key=lambda r: (int(r["route_id"]) if str(r["route_id"]).isdigit()
                                                else 0, str(r["route_id"]), r["repetition"])):
            w.writerow({k: (v.splitlines()[0] if isinstance(v, str) and v else v) for k, v in r.items()})
    os.replace(tmp, path)


def run_eval(jobs: list[Job], out: Path, workers: int, resume: bool, show_progress: bool = True) -> list[dict]:
    """Run jobs on ``workers`` processes; returns all records (old ones too when resuming)."""
    out.mkdir(parents=True, exist_ok=True)
    Path(jobs[0].log_dir if jobs else out / "logs").mkdir(parents=True, exist_ok=True)
    rec_path = out / "records.jsonl"
    done = read_records(rec_path) if resume else []
    if not resume:
        rec_path.write_text("")
    else:  # drop a torn last line so that appends start on a fresh line
        rec_path.write_text("".join(json.dumps(r) + "\n" for r in done))
    have = {r["key"] for r in done}
    todo = [j for j in jobs if j.key not in have]
    records = list(done)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="eval", unit="route",
               disable=not show_progress or None)
    ctx = mp.get_context("spawn")
    pending = list(reversed(todo))
    slots: dict = {}  # connection -> (process, job or None)

    def start_worker():
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_worker, args=(child,), daemon=True)
        p.start()
        child.close()
        slots[parent] = (p, None)

    with open(rec_path, "a") as f:
        def record(rec: dict) -> None:
            f.write(json.dumps(rec) + "\n")
            f.flush()
            os.fsync(f.fileno())
            records.append(rec)
            write_csv(records, out / "records.csv")
            bar.update(1)

        for _ in range(min(workers, len(todo))):
            start_worker()
        while slots:
            for conn, (p, job) in list(slots.items()):
                if job is None:
                    if pending:
                        nxt = pending.pop()
                        conn.send(nxt)
                        slots[conn] = (p, nxt)
                    else:
                        conn.send(None)
                        p.join()
                        del slots[conn]
            if not slots:
                break
            ready = wait(list(slots) + [p.sentinel for p, _ in slots.values()])
            for conn, (p, job) in list(slots.items()):
                if conn in ready:
                    try:
                        rec = conn.recv()
                    except (EOFError, OSError):
                        rec = None
                    if rec is not None:
                        record(rec)
                        slots[conn] = (p, None)
                        continue
                if p.sentinel in ready or not p.is_alive():
                    p.join()
                    del slots[conn]
                    if job is not None:
                        record(_crash_record(job, f"worker process died (exit code {p.exitcode})"))
                    if pending:
                        start_worker()
    bar.close()
    write_csv(records, out / "records.csv")
    return records
