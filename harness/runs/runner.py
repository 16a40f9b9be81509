"""The evaluation runner: routes fan out over worker processes, one libsumo each (SPEC §10).

Outputs in the run folder:

    records.jsonl   one JSON record per route run, appended and flushed as each ends
    records.csv     the same as a table, rewritten (atomically) after every route
    workers.jsonl   per route run: the worker process (host, pid), how many routes it has
                    run, and its resident memory after this one [MB] (the soak figure)
    logs/<route>_rep<k>.npz   the per-tick event log of that run (harness.loop.episode.EpisodeLog)

    run.json        what the run is (the software, harness.runs.provenance; every route run's
                    key, seed, route, agent, agent config and its digest, rules, step
                    deadline), written when it starts (a finished run scored again by
                    ``resume`` keeps the one it has)

Every route run gets its own seed, derived from the run seed, the route's place in its set
and the repetition (sumo_scimm.cli), so records do not depend on the number of workers or the
backend. A worker that dies (kill -9, segfault) has its route recorded as "Failed -
Simulation crashed" with the reason; a new worker takes over and the run goes on.
``resume`` keeps the complete records already in ``records.jsonl`` and runs only the rest
(a torn last line is dropped and redone); it refuses (BadInput) a folder whose run.json
differs from the resumed run's (other options, another checkpoint; other software when
records would be added), or whose records are not route runs of it, so a run's scores
never mix records of two runs.

Backends: ``local`` (spawned worker processes, each running routes one after another) and
``ray`` (harness.runs.ray_backend: each route a Ray task in a fresh process); both stream the
records into the same files in completion order.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import json
import multiprocessing as mp
import os
import signal
import socket
from dataclasses import dataclass
from multiprocessing.connection import wait
from pathlib import Path

import numpy as np
from tqdm import tqdm

from harness.scoring import criteria
from harness.common.atomic import savez_atomic, signals_held, write_atomic
from harness.loop.episode import AGENT_TIMEOUT
from harness.scoring.infractions import KEYS
from harness.runs.provenance import check_same_run, run_identity
from harness.scoring.scores import outside_lanes, route_record
from scenarios.routefile import Route

STABILITY = ("steering_jerk", "longitudinal_jerk", "curvature_variation", "speed_variation")

COUNT_KEYS = tuple(k for k in KEYS if k != "outside_route_lanes")
RECORD_FIELDS = ("key", "route_id", "repetition", "town", "status", "ds", "rc", "is", *COUNT_KEYS,
                 "outside_lanes_pct", "collisions_per_km", "km_driven", "length", "game_time", "wall_time",
                 "steps", *STABILITY, "seed", "message")
# the caller's failure message, as the leaderboard passes it to the status text
_CRASH = {criteria.FAILED_AGENT: "Agent crashed", criteria.FAILED_SIMULATION: "Simulation crashed",
          criteria.FAILED_SETUP: "Agent couldn't be set up"}


@dataclass(frozen=True)
class Job:
    index: int
    route: Route
    repetition: int
    agent: str
    agent_config: str | None
    seed: int
    log_dir: str
    rules: str = "lb2.0"
    collect_dir: str = ""  # if set, the episode is recorded there at 4 Hz (harness.expert.collect)
    route_file: str = ""
    agent_timeout: float = AGENT_TIMEOUT  # per-step deadline of run_step [s of wall time]

    @property
    def key(self) -> str:
        return f"{self.route.id}_rep{self.repetition}"


def route_seed(run_seed: int, index: int) -> int:
    """Seed of job ``index`` of a run: independent of worker count and order."""
    return int(np.random.SeedSequence([run_seed, index]).generate_state(1)[0])


def make_record(job: Job, status: str, rc: float, length: float, game_time: float, wall_time: float,
                steps: int, message: str, infractions: dict, stab: dict, rules: str) -> dict:
    """One line of records.jsonl: the Leaderboard record (``lb``) and flat columns."""
    lb = route_record(job.index, f"RouteScenario_{job.route.id}_rep{job.repetition}", infractions, rc,
                      {"route_length": length, "duration_game": game_time, "duration_system": wall_time},
                      rules, _CRASH.get(status, ""))
    sc = lb["scores"]
    km = length / 1000 * sc["score_route"] / 100
    n_coll = sum(len(lb["infractions"][k]) for k in ("collisions_layout", "collisions_pedestrian",
                                                      "collisions_vehicle"))
    out_pct = (outside_lanes(lb["infractions"]["outside_route_lanes"][0])[1]
               if lb["infractions"]["outside_route_lanes"] else 0.0)
    return {"key": job.key, "route_id": job.route.id, "repetition": job.repetition, "town": job.route.town,
            "status": lb["status"], "ds": sc["score_composed"], "rc": sc["score_route"], "is": sc["score_penalty"],
            **{k: len(lb["infractions"][k]) for k in COUNT_KEYS}, "outside_lanes_pct": out_pct,
            "collisions_per_km": round(n_coll / km, 3) if km > 0 else float("nan"),
            "km_driven": round(km, 6), "length": round(length, 3), "game_time": round(game_time, 3),
            "wall_time": round(wall_time, 3), "steps": steps, **{k: stab.get(k, float("nan")) for k in STABILITY},
            "seed": job.seed, "message": message, "episode_status": status, "lb": lb}


def run_job(job: Job) -> dict:
    """Drive one route, save its log, detect infractions; returns the route record (in a worker)."""
    from harness.loop.episode import run_episode
    from harness.scoring.infractions import detect
    from harness.scoring.stability import stability
    from sumo_nets import load_net
    recorder = None
    if job.collect_dir:
        from harness.expert.collect import Recorder
        recorder = Recorder()
    res = run_episode(job.route, job.agent, job.agent_config, job.seed,
                      on_frame=recorder.on_frame if recorder else None, agent_timeout=job.agent_timeout)
    arrays = res.log.arrays()
    savez_atomic(Path(job.log_dir) / f"{job.key}.npz", **arrays)
    if res.plan is not None:
        infractions = detect(arrays, res.plan, job.route, load_net(job.route.town), res.status, job.rules)
    else:
        infractions = {k: [] for k in KEYS}
    record = make_record(job, res.status, res.rc, res.length, res.game_time, res.wall_time, res.steps,
                         res.message, infractions, stability(arrays), job.rules)
    if recorder is not None:
        from harness.expert.collect import save_episode
        save_episode(Path(job.collect_dir) / f"{job.key}.npz", recorder.arrays(), job.route_file,
                     job.route.id, job.route.town, record)
    return record


def crash_record(job: Job, reason: str) -> dict:
    """The record of a route whose simulation or worker failed: "Failed - Simulation crashed"."""
    return make_record(job, criteria.FAILED_SIMULATION, 0.0, float(job.route.length), 0.0, 0.0, 0, reason,
                       {k: [] for k in KEYS}, {}, job.rules)


def run_job_safely(job: Job) -> dict:
    """run_job, with a harness error turned into the route's crash record (the run goes on)."""
    try:
        return run_job(job)
    except Exception as exc:  # noqa: BLE001 - a harness bug fails this route, not the run
        return crash_record(job, f"{type(exc).__name__}: {exc}")


def rss_mb() -> float:
    """Resident memory of this process [MB] (Linux /proc; elsewhere the peak, from getrusage)."""
    try:
        with open("/proc/self/statm") as f:
            return round(int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20, 1)
    except (OSError, ValueError, IndexError):
        import resource
        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)  # KiB on Linux


def release_freed_memory() -> bool:
    """Hand the heap pages freed since the last call back to the system (glibc's
    ``malloc_trim``); returns whether it could (False off glibc, e.g. macOS or musl).

    A route's log, metrics and temporaries grow with its length and are freed when it ends,
    but glibc keeps freed pages mapped below a live block: without this, a worker's resident
    memory keeps the high-water mark of its longest route so far (+9 MB after the 8,563-tick
    route 46 of town12_short), which reads as growth in the soak figure (docs/reliability.md)."""
    global _libc
    if _libc is None:
        try:
            lib = ctypes.CDLL(ctypes.util.find_library("c")) if os.name == "posix" else None
        except OSError:
            lib = None
        _libc = lib if lib is not None and hasattr(lib, "malloc_trim") else False
    if _libc is False:
        return False
    _libc.malloc_trim(0)
    return True


_libc = None  # glibc once loaded by release_freed_memory, False where there is none


def worker_stats(routes_run: int) -> dict:
    """This worker process after a route: host, pid, routes it has run, resident memory [MB]."""
    return {"host": socket.gethostname(), "pid": os.getpid(), "routes": routes_run, "rss_mb": rss_mb()}


def _worker(conn) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which ends its workers
    routes_run = 0
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if job is None:
            return
        rec = run_job_safely(job)
        routes_run += 1
        release_freed_memory()  # before the memory sample: what the worker holds, not its peak
        try:
            conn.send((rec, worker_stats(routes_run)))
        except OSError:  # the parent is gone (killed): nobody to report to
            return


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


def _keep_complete_lines(path: Path, resume: bool) -> list[dict]:
    """Start a JSON-lines file afresh, or (resume) keep its complete lines; replaced
    atomically, so nothing is lost meanwhile, and appends start on a fresh line."""
    kept = read_records(path) if resume else []
    write_atomic(path, "".join(json.dumps(r) + "\n" for r in kept))
    return kept


def _run_local(jobs: list[Job], workers: int, emit) -> None:
    """Run jobs on ``workers`` spawned processes; ``emit(job, record, stats)`` as each ends
    (stats None when the worker died). Interrupted (Ctrl-C), it ends its workers."""
    ctx = mp.get_context("spawn")
    pending = list(reversed(jobs))
    slots: dict = {}  # connection -> (process, job or None)

    def start_worker():
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_worker, args=(child,), daemon=True)
        p.start()
        child.close()
        slots[parent] = (p, None)

    try:
        for _ in range(min(workers, len(jobs))):
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
                        rec, stats = conn.recv()
                    except (EOFError, OSError):
                        rec = None
                    if rec is not None:
                        emit(job, rec, stats)
                        slots[conn] = (p, None)
                        continue
                if p.sentinel in ready or not p.is_alive():
                    p.join()
                    del slots[conn]
                    if job is not None:
                        emit(job, crash_record(job, f"worker process died (exit code {p.exitcode})"), None)
                    if pending:
                        start_worker()
    finally:
        for p, _ in slots.values():  # only after an interruption or an error
            p.terminate()
            p.join()


def run_eval(jobs: list[Job], out: Path, workers: int | None, resume: bool, show_progress: bool = True,
             checkpoint: Path | None = None, sensors: list[str] | None = None, backend: str = "local",
             address: str | None = None) -> list[dict]:
    """Run jobs on ``workers`` processes (local) or Ray tasks (``backend="ray"``, on the
    cluster at ``address``, or a local Ray); returns all records (old ones too when resuming).
    After every route: records.jsonl and workers.jsonl (appended), records.csv and
    results.json (rewritten); at the end also summary.csv. ``workers`` None: every core
    (local) or every CPU of the Ray cluster."""
    from harness.scoring.outputs import write_outputs
    identity = run_identity(jobs)
    kept = read_records(out / "records.jsonl") if resume else []
    adding = not resume or bool({j.key for j in jobs} - {r["key"] for r in kept})
    if resume:  # before Ray starts: a refused resume starts nothing
        check_same_run(out, identity, kept, adding)
    pool = None
    if backend == "ray":  # connect first: a cluster that cannot be reached leaves no file behind
        from harness.runs.ray_backend import RayPool
        pool = RayPool(address, workers)
    try:
        checkpoint = checkpoint or out / "results.json"
        sensors = sensors or []
        out.mkdir(parents=True, exist_ok=True)
        dirs = {j.log_dir for j in jobs} | {j.collect_dir for j in jobs if j.collect_dir}
        for d in dirs or {str(out / "logs")}:
            Path(d).mkdir(parents=True, exist_ok=True)
        rec_path, workers_path = out / "records.jsonl", out / "workers.jsonl"
        if adding:  # a finished run scored again keeps the run.json of the software that made it
            write_atomic(out / "run.json", json.dumps(identity, indent=1) + "\n")
        done = _keep_complete_lines(rec_path, resume)
        _keep_complete_lines(workers_path, resume)
        have = {r["key"] for r in done}
        todo = [j for j in jobs if j.key not in have]
        records = list(done)
        bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="eval", unit="route",
                   disable=not show_progress or None)
        with open(rec_path, "a") as f, open(workers_path, "a") as wf:
            def emit(job: Job, rec: dict, stats: dict | None) -> None:
                with signals_held():  # the route's lines and the rewritten tables, all or none
                    f.write(json.dumps(rec) + "\n")
                    f.flush()
                    os.fsync(f.fileno())
                    records.append(rec)
                    if stats is not None:
                        wf.write(json.dumps({"key": job.key, **stats}) + "\n")
                        wf.flush()
                    write_outputs(records, len(jobs), out, checkpoint, sensors, finished=False, summary=False)
                bar.update(1)

            if pool is not None:
                pool.run(todo, emit)
            else:
                _run_local(todo, workers or os.cpu_count() or 1, emit)
        bar.close()
    finally:
        if pool is not None:
            pool.close()
    with signals_held():
        write_outputs(records, len(jobs), out, checkpoint, sensors, finished=len(records) == len(jobs))
    return records


def rss_summary(out: Path) -> dict | None:
    """Worker memory over a run, from its workers.jsonl: for each worker process, the
    resident memory after its first and after its last route [MB]. ``growth_mb`` is the
    largest last - first over the workers, ``slope_mb_per_100`` the largest least-squares
    trend (MB per 100 routes) of a worker that ran >= 3 routes; None without samples."""
    path = out / "workers.jsonl"
    rows = read_records(path) if path.exists() else []
    by_worker: dict[tuple, list[tuple[int, float]]] = {}
    for r in rows:
        by_worker.setdefault((r.get("host"), r["pid"]), []).append((r["routes"], r["rss_mb"]))
    if not by_worker:
        return None
    growth, slope = [], []
    for samples in by_worker.values():
        samples.sort()
        growth.append(samples[-1][1] - samples[0][1])
        if len(samples) >= 3:
            n, mb = np.array(samples, dtype=float).T
            slope.append(float(np.polyfit(n, mb, 1)[0]) * 100)
    return {"routes": len(rows), "workers": len(by_worker),
            "max_routes_per_worker": max(len(s) for s in by_worker.values()),
            "first_mb": max(s[0][1] for s in by_worker.values()),
            "peak_mb": max(mb for s in by_worker.values() for _, mb in s),
            "growth_mb": round(max(growth), 1),
            "slope_mb_per_100": round(max(slope), 2) if slope else float("nan")}
