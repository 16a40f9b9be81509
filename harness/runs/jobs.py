"""One route run as a job: its seed, driving it in this process, and its record (docs/design.md §10).

A ``Job`` is what a worker (a local process or a Ray task) gets; ``run_job`` drives the
route, saves its per-tick log (``logs/<route>_rep<k>.npz``), detects the infractions and
returns the route's record (columns in harness.scoring.records). ``run_job_safely`` turns a
harness error into the route's "Failed - Simulation crashed" record, so the run goes on.
Under ``--rules b2d`` it also writes Bench2Drive's ``metric_info.json`` of the route into
``b2d/<save_name>/`` beside the logs folder (harness.scoring.bench2drive).
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import socket
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.ego import DEFAULT_VEHICLE
from files.atomic import savez_atomic
from harness.common.lock import check_folder
from harness.loop.deadline import AGENT_TIMEOUT
from harness.scoring.bench2drive import record_keys
from harness.scoring.infractions import KEYS
from harness.scoring.records import COUNT_KEYS, STABILITY
from harness.scoring.scores import outside_lanes, route_record
from harness.scoring.statuses import COMPLETED, FAILED_AGENT, FAILED_SIMULATION, crash_message
from scenarios.routefile import Route

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
    vehicle: str = DEFAULT_VEHICLE  # the ego model (controller.ego)
    folder: tuple = ()  # (device, inode) of the run folder, checked before a file is written

    @property
    def key(self) -> str:
        return f"{self.route.id}_rep{self.repetition}"


def route_seed(run_seed: int, index: int) -> int:
    """Seed of job ``index`` of a run: independent of worker count and order."""
    return int(np.random.SeedSequence([run_seed, index]).generate_state(1)[0])


B2D_DIR = "b2d"  # Bench2Drive's metric_info folders, beside the logs folder


def b2d_dir(job: Job) -> Path:
    """The folder of a job's Bench2Drive metric_info files: ``b2d`` beside its logs folder."""
    return Path(job.log_dir).parent / B2D_DIR


def b2d_keys(job: Job) -> dict:
    """Bench2Drive's record keys of a job (its route's first hazard is the scenario)."""
    first = job.route.hazards[0].name if job.route.hazards else None
    return record_keys(job.route.id, job.repetition, job.route.town, first)


def make_record(job: Job, status: str, rc: float, length: float, game_time: float, wall_time: float,
                steps: int, message: str, infractions: dict, stab: dict, rules: str, *,
                outside_pct: float | None = None, efficiency: float | None = None,
                smoothness: float | None = None) -> dict:
    """One line of records.jsonl: the Leaderboard record (``lb``; with Bench2Drive's keys
    under b2d rules) and flat columns, among them the route's first hazard type and its
    Bench2Drive efficiency [%] and smoothness [0, 1] (None where undefined).
    ``outside_pct``: the unrounded outside-lanes percentage, which the penalty uses."""
    lb = route_record(job.index, f"RouteScenario_{job.route.id}_rep{job.repetition}", infractions,
                      100 if status == COMPLETED else rc,  # the leaderboard's completed RC is the int 100
                      {"route_length": length, "duration_game": game_time, "duration_system": wall_time},
                      rules, crash_message(status), outside_pct, b2d_keys(job) if rules == "b2d" else None)
    sc = lb["scores"]
    km = length / 1000 * sc["score_route"] / 100
    n_coll = sum(len(lb["infractions"][k]) for k in ("collisions_layout", "collisions_pedestrian",
                                                      "collisions_vehicle"))
    out_pct = (outside_lanes(lb["infractions"]["outside_route_lanes"][0])[1]
               if lb["infractions"]["outside_route_lanes"] else 0.0)
    return {"key": job.key, "route_id": job.route.id, "repetition": job.repetition, "town": job.route.town,
            "status": lb["status"], "ds": sc["score_composed"], "rc": float(sc["score_route"]),
            "is": sc["score_penalty"],
            **{k: len(lb["infractions"][k]) for k in COUNT_KEYS}, "outside_lanes_pct": out_pct,
            "collisions_per_km": round(n_coll / km, 3) if km > 0 else float("nan"),
            "km_driven": round(km, 6), "length": round(length, 3), "game_time": round(game_time, 3),
            "wall_time": round(wall_time, 3), "steps": steps, **{k: stab.get(k, float("nan")) for k in STABILITY},
            "seed": job.seed, "message": message, "episode_status": status,
            "hazard": job.route.hazards[0].type if job.route.hazards else "", "efficiency": efficiency,
            "smoothness": smoothness, "lb": lb}


def run_job(job: Job) -> dict:
    """Drive one route, save its log, detect infractions; returns the route record (in a worker)."""
    from harness.loop.episode import run_episode
    from harness.scoring.bench2drive import metric_info, route_efficiency, route_smoothness, write_metric_info
    from harness.scoring.infractions import detect, min_speed
    from harness.scoring.stability import stability
    from harness.scoring.statuses import ended_by_criterion
    from sumo_nets import load_net
    recorder = None
    if job.collect_dir:
        from harness.expert.collect import Recorder
        recorder = Recorder()
    res = run_episode(job.route, job.agent, job.agent_config, job.seed,
                      on_frame=recorder.on_frame if recorder else None, agent_timeout=job.agent_timeout,
                      vehicle=job.vehicle)
    arrays = res.log.arrays()
    if job.folder:
        check_folder(Path(job.log_dir).parent, job.folder)
    savez_atomic(Path(job.log_dir) / f"{job.key}.npz", **arrays)
    values: dict = {}
    infractions, speed = {k: [] for k in KEYS}, []
    if res.plan is not None:
        infractions = detect(arrays, res.plan, job.route, load_net(job.route.town), res.status, job.rules, values)
        if job.rules == "b2d":  # Bench2Drive's checkpoints, every one logged: its efficiency's input
            speed = infractions["min_speed_infractions"]
        elif len(arrays["t"]):
            speed = min_speed(arrays, res.plan, "b2d", ended_by_criterion(res.status))
    info = metric_info(arrays)
    if job.rules == "b2d":
        write_metric_info(b2d_dir(job) / b2d_keys(job)["save_name"] / "metric_info.json", info)
    record = make_record(job, res.status, res.rc, res.length, res.game_time, res.wall_time, res.steps,
                         res.message, infractions, stability(arrays), job.rules,
                         outside_pct=values.get("outside_route_lanes"), efficiency=route_efficiency(speed),
                         smoothness=route_smoothness(info))
    if recorder is not None:
        from harness.expert.collect import save_episode
        save_episode(Path(job.collect_dir) / f"{job.key}.npz", recorder.arrays(), job.route_file,
                     job.route.id, job.route.town, record, job.vehicle)
    return record


def crash_record(job: Job, reason: str, status: str = FAILED_SIMULATION) -> dict:
    """The record of a route whose simulation or worker failed: "Failed - Simulation crashed"
    (or ``status``)."""
    return make_record(job, status, 0.0, traced_length(job.route), 0.0, 0.0, 0, reason,
                       {k: [] for k in KEYS}, {}, job.rules)


# A worker whose agent call runs this long past its deadline [s] is ended (by the parent,
# harness.runs.workers; in a Ray task by its own watch thread, harness.runs.ray_backend):
# the agent ignored, cancelled or swallowed the in-process alarm, or hangs outside
# run_step. Checked every WATCH_EVERY s, so a hung route ends within its deadline + 4 s
# and the time it takes to end the process.
KILL_AFTER, WATCH_EVERY = 3.0, 1.0


def hung_record(job: Job) -> dict:
    """The record of a route whose agent hung in a call past its deadline, its worker
    killed: "Failed - Agent crashed" with the Leaderboard's timeout words."""
    return crash_record(job, hung_message(job.agent_timeout), FAILED_AGENT)


def hung_message(timeout: float) -> str:
    """What a route's record (or replay row) says of an agent call that ran past ``timeout`` [s]."""
    return f"Agent took longer than {timeout:g}s to return from a call (its worker process was ended)"


def traced_length(route: Route) -> float:
    """The route's length along its traced lanes [m], the figure a driven route's record has
    (the episode's plan); the route file's ``length`` (the same to the cm) if the route
    cannot be traced."""
    from scenarios.geometry import trace
    from sumo_nets import load_net
    try:
        return trace(load_net(route.town), list(route.edges), route.depart_pos, route.arrival_pos).length
    except (ValueError, KeyError, OSError):  # a route or net that does not trace (RouteError, UnknownTown)
        return float(route.length)


def run_job_safely(job: Job) -> dict:
    """run_job, with a harness error turned into the route's crash record (the run goes on).
    An OSError (a log that cannot be written, a net that cannot be read) is no driving
    result: it propagates, and the run stops (harness.runs.runner)."""
    try:
        return run_job(job)
    except OSError:
        raise
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
