"""``sumo-scimm replay``: several agents fed the identical input sequence of a reference run.

Closed-loop stability mixes two things: how stable a model's outputs are, and what it was
exposed to (arms drive other trajectories, meet other traffic, stand for other times).
Replay takes the exposure out. For each route of a reference run (any agent's, e.g. the
expert's) it rebuilds every tick's scene from the run's log (harness.loop.scene_log),
renders the BEV with the closed-loop renderer (bit for bit the BEV of the run), and gives
every replayed agent the same sensor data the reference agent got that tick: BEV, target
point, ego speed, command, pose (harness.loop.episode.sensor_inputs). The agents' controls
drive nothing: the ego moves as it did in the reference run. Each agent's outputs (its
controller's steer, throttle, brake; its predicted path and speed waypoints) give the
stability metrics of harness.scoring.stability on the reference's moving ticks; arms are
then compared route-paired with intervals (harness.scoring.report.compare).

Each agent is built once for the checks (on the first route's plan, its ``sensors()``
validated after ``setup()``) and once per worker process, and set up afresh for every
route (``set_global_plan``, ``setup``, ``sensors``), as in ``eval``; the output folder is
held (harness.common.lock) while the replay runs. Agents that read the privileged
``world`` sensor are refused (the log keeps
what the BEV draws, not the ids and speeds the expert reads). An agent that raises on a
route gets a row with its message and no metrics there; the replay goes on. Every agent
call runs under the deadline ``--agent-timeout`` (as in ``eval``): a ``run_step`` past it
is interrupted by an alarm, and a worker whose agent hangs anyway (the alarm ignored or
swallowed, a hang in ``setup``, ``sensors`` or ``destroy``) is killed by the parent
(harness.runs.workers); that agent's row of the route says so and has no metrics, the
route is replayed again by a new worker for the other agents. The table's paired figures
leave out a route whose row has no metrics, as for an agent that raised.

Outputs in ``--out``:

    replay.csv           one row per route and agent: key, route, agent, ticks, moving
                         ticks, message, the stability metrics
    outputs/<key>.npz    per agent i: a<i>_steer, a<i>_throttle, a<i>_brake (T,),
                         a<i>_pred_path (T, 20, 2), a<i>_pred_speed_wps (T, 10, 2) [m] ego frame
    table.csv, table.md  the agents compared with the first (harness.scoring.report)
    replay.json          the reference run, the agents, the routes and the software
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from files.atomic import savez_atomic, write_atomic
from harness.common.errors import BadInput
from harness.common.lock import FolderLock
from harness.common.progress import progress as show_progress
from harness.loop.agent import (agent_call, agent_for, check_agent_setup, exception_text, forget_agent, split_output,
                                validate_sensors)
from harness.loop.deadline import AGENT_TIMEOUT, deadline_alarm, step_with_deadline
from harness.loop.episode import sensor_inputs
from harness.runs.jobs import hung_message
from harness.runs.workers import HUNG, run_workers
from harness.loop.scene_log import has_scene, scene_at
from harness.scoring.records import STABILITY
from harness.scoring.report import compare, markdown, stability_figures
from harness.scoring.stability import OTHER, TABLE4, moving_ticks, stability

LOG_KEYS = ("v", "steer", "throttle", "brake", "pred_path", "pred_speed_wps")
COLUMNS = ("key", "route_id", "agent", "ticks", "moving_ticks", "message", *STABILITY)


@dataclass(frozen=True)
class ReplayJob:
    """One route of the reference run and the agents to feed its inputs."""

    key: str
    route: object  # scenarios.routefile.Route
    log: str  # the reference run's log of this route
    agents: tuple[str, ...]  # as the user named them (the rows' labels)
    names: tuple[str, ...]  # the agents to load (harness.loop.agent.load_agent)
    configs: tuple[str | None, ...]  # their setup() configs
    out: str  # the folder of the outputs/<key>.npz files
    timeout: float = AGENT_TIMEOUT  # deadline of each agent call [s of wall time] (--agent-timeout)
    dropped: tuple[tuple[int, str], ...] = ()  # (agent's place, message): agents not run on this route


def route_digest(route) -> str:
    """The route's hash as run.jsonc records it (harness.runs.provenance.run_identity)."""
    return hashlib.sha256(repr(route).encode()).hexdigest()[:16]


LOG_FIX = "evaluate the reference again"
# what replay_route reads of a reference log: one row per tick, a row's shape (None: any size)
TICK_ROWS = {"scene_t": (), "scene_ego": (4,), "scene_progress": (), "scene_lights": (None,),
             "scene_stops": (None,)}
ACTOR_ROWS = {"scene_xy": (2,), "scene_yaw": (), "scene_size": (2,), "scene_cls": ()}


def check_log(log: Path) -> None:
    """BadInput naming the reference log and the fix unless it can be replayed: readable
    (harness.common.npz.read_npz), with the scene state of this sumo-scimm, every
    ``scene_*`` array holding one row per tick and the actors counted up by scene_offset.
    Reads the arrays' headers and scene_offset only."""
    from harness.common.npz import check_offsets, check_rows, npz_headers, read_npz
    heads = npz_headers(log, "log", LOG_FIX)
    if "scene_t" in heads and "scene_stops" not in heads:
        raise BadInput(f"{log} keeps no stop-sign state (a run from before the BEV drew stop signs until "
                       "obeyed): evaluate the reference again with this sumo-scimm")
    if not has_scene(heads):
        raise BadInput(f"{log} keeps no scene state (a run from before scenes were logged): evaluate "
                       "the reference again with this sumo-scimm")
    n = check_rows(heads, TICK_ROWS, log, "log", LOG_FIX)
    check_rows(heads, {"steer": ()}, log, "log", LOG_FIX)
    check_rows(heads, {"scene_props": (5,)}, log, "log", LOG_FIX)
    check_offsets({**heads, **read_npz(log, "log", LOG_FIX, ("scene_offset",))}, "scene_offset", ACTOR_ROWS, n,
                  log, "log", LOG_FIX)


def _load_log(path: str) -> dict[str, np.ndarray]:
    from harness.common.npz import read_npz
    return read_npz(Path(path), "log", LOG_FIX)


def replay_route(job: ReplayJob) -> list[dict]:
    """Feed every agent the reference's inputs on one route; returns a row per agent
    (COLUMNS) and writes the agents' outputs to ``out/<key>.npz``."""
    from harness.sensors.bev import BevRenderer  # pulls OpenCV: imported where it is used
    from harness.sim.plan import build_plan
    from sumo_nets import load_net
    log = _load_log(job.log)
    route = job.route
    plan = build_plan(route, load_net(route.town))
    bev = BevRenderer.for_town(route.town)
    n = min(len(log["scene_t"]), len(log["steer"]))
    outs = [{"steer": np.full(n, np.nan), "throttle": np.full(n, np.nan), "brake": np.full(n, np.nan),
             "pred_path": np.full((n, 20, 2), np.nan, np.float32),
             "pred_speed_wps": np.full((n, 10, 2), np.nan, np.float32)} for _ in job.agents]
    agents, specs, messages = [], [], [""] * len(job.agents)
    dropped = dict(job.dropped)
    for i, (name, config) in enumerate(zip(job.names, job.configs)):
        if i in dropped:
            agents.append(None)
            specs.append([])
            messages[i] = dropped[i]
            continue
        try:
            with agent_call(job.timeout, i):
                agent = agent_for(name, i)  # a slot per agent: two checkpoints share the name 'student'
            with agent_call(job.timeout, i):
                agent.set_global_plan(plan)
                agent.setup(config)
            with agent_call(job.timeout, i):
                spec = agent.sensors()
            validate_sensors(spec)
        except Exception as exc:  # noqa: BLE001 - an agent failure is its row's message
            forget_agent(name, i)
            agent, spec, messages[i] = None, [], f"set-up failed: {type(exc).__name__}: {exc}"
        agents.append(agent)
        specs.append(spec)
    alarm = deadline_alarm()
    for t in range(n if any(a is not None for a in agents) else 0):
        sc = scene_at(log, t)
        frame = bev.render(sc.ego, sc.snap, plan, sc.lights, sc.props, sc.stops)
        for i, agent in enumerate(agents):
            if agent is None:
                continue
            try:
                inputs = sensor_inputs(specs[i], sc.ego, plan, sc.progress, sc.snap, None, frame.copy)
                control, pred = split_output(step_with_deadline(agent, inputs, sc.timestamp, job.timeout, alarm, i))
            except Exception as exc:  # noqa: BLE001
                messages[i] = f"tick {t}: {type(exc).__name__}: {exception_text(exc)}"
                forget_agent(job.names[i], i)
                agents[i] = None
                continue
            o = outs[i]
            o["steer"][t], o["throttle"][t], o["brake"][t] = control.steer, control.throttle, control.brake
            if pred is not None and pred.path is not None:
                o["pred_path"][t] = pred.path
            if pred is not None and pred.speed_wps is not None:
                o["pred_speed_wps"][t] = pred.speed_wps
    for i, agent in enumerate(agents):
        try:
            if agent is not None:
                with agent_call(job.timeout, i):
                    agent.destroy()
        except Exception as exc:  # noqa: BLE001 - destroy errors must not hide the route's outputs
            messages[i] = messages[i] or f"destroy() raised {type(exc).__name__}: {exception_text(exc)}"
            forget_agent(job.names[i], i)
    savez_atomic(Path(job.out) / f"{job.key}.npz", **{f"a{i}_{k}": v for i, o in enumerate(outs) for k, v in o.items()})
    v = log["v"][:n]
    moving = int(moving_ticks(v).sum())
    return [_row(job, i, n, moving, messages[i], stability({"v": v, **o}) if not messages[i] else None)
            for i, o in enumerate(outs)]


def _row(job: ReplayJob, i: int, ticks: int, moving: int, message: str, metrics: dict | None) -> dict:
    """Agent ``i``'s row of the job's route (COLUMNS); ``metrics`` None: NaN (a failed agent)."""
    return {"key": job.key, "route_id": job.route.id, "agent": job.agents[i], "ticks": ticks,
            "moving_ticks": moving, "message": message, **(metrics or dict.fromkeys(STABILITY, float("nan")))}


def _routes_of_run(run: Path, routes: str | None) -> dict[str, object]:
    """{route run key: Route} of a reference run: its run.jsonc names each route by a hash,
    found in ``routes`` (a set name or file) or, without it, in the shipped route sets."""
    from scenarios import resolve_set
    from scenarios.make import SETS_DIR
    from scenarios.routefile import read_routes
    try:
        from harness.runs.provenance import run_file
        runs = json.loads(run_file(run).read_text())["route_runs"]
        wanted = {key: r["route"] for key, r in runs.items()}
    except (OSError, ValueError, KeyError, TypeError):
        raise BadInput(f"{run}: no readable run.jsonc: give a run folder of 'sumo-scimm eval'") from None
    files = [resolve_set(routes)] if routes else sorted(SETS_DIR.glob("*.xml"))
    found = {}
    for f in files:
        for r in read_routes(f)[1]:
            found.setdefault(route_digest(r), r)
    out = {key: found[d] for key, d in wanted.items() if d in found}
    for key, route in out.items():  # a key names the route's files: <route id>_rep<k>
        if not re.fullmatch(rf"{re.escape(route.id)}_rep[0-9]{{1,9}}", key):
            raise BadInput(f"{run}: run.jsonc names route run {key[:40]!r}, not <route id>_rep<k>: the run folder "
                           "is damaged; evaluate the reference again")
    missing = sorted(set(wanted) - set(out))
    if missing:
        where = f"route file {routes}" if routes else "any shipped route set"
        raise BadInput(f"{run}: route run {missing[0]} drove a route that is not in {where}: give its set with --routes")
    return out


def check_agents(agents: list[str], plan=None,
                 timeout: float = AGENT_TIMEOUT) -> tuple[list[str], list[str | None]]:
    """The agents' names and configs (``--agent NAME``, ``module:Class`` or ``PATH.pt``),
    checked, each built once (harness.loop.agent.check_agent_setup, on a route's ``plan``,
    each call within ``timeout`` [s]): BadInput for an unknown or repeated one, or one
    that reads the ``world``."""
    if not agents:
        raise BadInput("replay needs at least one --agent")
    if len(set(agents)) < len(agents):
        raise BadInput(f"--agent {next(a for a in agents if agents.count(a) > 1)!r} is given twice")
    names, configs = [], []
    for a in agents:
        name, config, specs = check_agent_setup(a, None, plan, timeout)
        if any(s.get("type") == "world" for s in specs):
            raise BadInput(f"--agent {a!r} reads the privileged 'world' sensor, which a replay cannot give "
                           "(the log keeps what the BEV draws): replay agents that drive from the BEV")
        names.append(name)
        configs.append(config)
    return names, configs


def plan_replay(run: Path, agents: list[str], out: Path | None, routes: str | None = None,
                subset: str | None = None, timeout: float = AGENT_TIMEOUT) -> list[ReplayJob]:
    """The replay's jobs, every input checked first (BadInput naming the problem and the fix);
    ``out`` None: check the reference and the agents only. ``timeout``: the deadline of
    every agent call [s] (--agent-timeout)."""
    from harness.runs.evaluate import check_agent_timeout
    check_agent_timeout(timeout)
    from harness.runs.evaluate import select_routes
    if not (run / "logs").is_dir():
        raise BadInput(f"{run} is not a run folder of 'sumo-scimm eval' (no logs/)")
    if out is not None and (out / "replay.csv").exists():
        raise BadInput(f"{out} already holds a replay: choose another --out")
    by_key = _routes_of_run(run, routes)
    from harness.runs.evaluate import first_plan
    names, configs = check_agents(agents, first_plan(next(iter(by_key.values()))) if by_key else None, timeout)
    ids = sorted({r.id for r in by_key.values()}, key=lambda i: (len(i), i))
    keep = set(select_routes(subset, ids))
    jobs = []
    for key, route in sorted(by_key.items(), key=lambda kv: (int(kv[1].id) if kv[1].id.isdigit() else 0, kv[0])):
        if route.id not in keep:
            continue
        log = run / "logs" / f"{key}.npz"
        if not log.is_file():
            raise BadInput(f"{run}: no log of route run {key} ({log}): finish the run with 'sumo-scimm eval --resume'")
        check_log(log)
        jobs.append(ReplayJob(key, route, str(log), tuple(agents), tuple(names), tuple(configs),
                              str(out / "outputs") if out is not None else "", timeout))
    if not jobs:
        raise BadInput(f"--routes-subset {subset!r} selects no route run of {run}")
    return jobs


def run_replay(jobs: list[ReplayJob], workers: int | None = None, progress: bool = True) -> list[dict]:
    """Every job's rows, on ``workers`` spawned processes (None: every core) watched by this
    one (harness.runs.workers). A worker killed in an agent's call past its deadline +
    KILL_AFTER (or dead in one) fails that agent on that route, as an agent that raises
    there: the route is replayed again by a new worker without it (the other agents' rows
    as from an undisturbed replay), its row keeping the message and no metrics. A worker
    dead outside an agent's call fails the route for every agent (rows of 0 ticks), and
    the route is not replayed again."""
    workers = min(workers or os.cpu_count() or 1, len(jobs))
    rows: list[dict] = []
    bar = show_progress(total=len(jobs), desc="replay", unit="route", show=progress)

    def emit(job: ReplayJob, out: list[dict]) -> None:
        rows.extend(out)
        bar.update(1)

    def lost(job: ReplayJob, reason, caller: int | None) -> ReplayJob | None:
        words = hung_message(job.timeout) if reason == HUNG else f"worker process died (exit code {reason})"
        gone = dict(job.dropped)
        if caller is None:
            emit(job, [_row(job, i, 0, 0, gone.get(i, words), None) for i in range(len(job.agents))])
            return None
        gone[caller] = words
        return dataclasses.replace(job, dropped=tuple(sorted(gone.items())))

    run_workers(jobs, workers, replay_route, emit, lost)
    bar.close()
    order = {j.key: i for i, j in enumerate(jobs)}
    agents = list(jobs[0].agents)
    return sorted(rows, key=lambda r: (order[r["key"]], agents.index(r["agent"])))


def replay(run: Path, agents: list[str], out: Path, *, routes: str | None = None, subset: str | None = None,
           workers: int | None = None, n_boot: int = 2000, progress: bool = True,
           labels: list[str] | None = None, agent_timeout: float = AGENT_TIMEOUT) -> str:
    """Replay reference run ``run`` with ``agents`` into ``out`` (module docstring); returns
    the comparison table as Markdown. ``labels``: names for the agents in replay.csv and the
    table (e.g. arm names for checkpoint paths; default the ``agents`` strings).
    ``agent_timeout``: the deadline of every agent call [s of wall time]."""
    if labels is not None and (len(labels) != len(agents) or len(set(labels)) < len(labels)):
        raise ValueError(f"labels {labels} must name each of the {len(agents)} agents once")
    with FolderLock(out):
        return _replay_held(run, agents, out, routes, subset, workers, n_boot, progress, labels, agent_timeout)


def _replay_held(run: Path, agents: list[str], out: Path, routes: str | None, subset: str | None,
                 workers: int | None, n_boot: int, progress: bool, labels: list[str] | None,
                 agent_timeout: float) -> str:
    """``replay`` in the output folder it holds."""
    from harness.runs.provenance import software
    jobs = plan_replay(run, agents, out, routes, subset, agent_timeout)
    (out / "outputs").mkdir(parents=True, exist_ok=True)
    rows = run_replay(jobs, workers, progress)
    names = dict(zip(agents, labels or agents))
    for r in rows:
        r["agent"] = names[r["agent"]]

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8", errors="backslashreplace") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            w.writerows(rows)
    write_atomic(out / "replay.csv", write)
    md = replay_table(rows, [names[a] for a in jobs[0].agents], out, n_boot)
    write_atomic(out / "replay.json", json.dumps({"reference": str(run.resolve()), "agents": list(jobs[0].agents),
                                                  "labels": [names[a] for a in jobs[0].agents],
                                                  "configs": list(jobs[0].configs), "routes": [j.key for j in jobs],
                                                  "software": software()}, indent=1) + "\n")
    return md


def replay_table(rows: list[dict], agents: list[str], out: Path, n_boot: int = 2000) -> str:
    """The agents compared with the first, route-paired (harness.scoring.report.compare):
    ``out/table.csv`` and ``table.md``; returns the Markdown."""
    from harness.scoring.report import csv_rows
    arms = {a: [{r["key"]: r for r in rows if r["agent"] == a}] for a in agents}
    main = stability_figures(TABLE4)
    other = tuple(f for f in stability_figures(OTHER) if f[0] != "standing_share")  # the reference's, for all
    figures = (*main, *other)
    res = compare(arms, figures, n_boot=n_boot)
    ticks = sum(r["ticks"] for r in rows if r["agent"] == agents[0])
    moving = sum(r["moving_ticks"] for r in rows if r["agent"] == agents[0])
    md = (markdown(res, arms, main, "Replay: output stability on the reference run's inputs (moving ticks)")
          + "\n\n" + markdown(res, arms, other, "Replay, other readings")
          + f"\n\n{len(arms[agents[0]][0])} routes, {ticks} ticks of which {moving} moving.")
    table = csv_rows(res, arms, figures)

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8", errors="backslashreplace") as f:
            w = csv.DictWriter(f, fieldnames=list(table[0]))
            w.writeheader()
            w.writerows(table)
    write_atomic(out / "table.csv", write)
    write_atomic(out / "table.md", md + "\n")
    return md


REPLAY_AGENTS = ("baseline", "fixed", "scimm")  # the bench's replay: three of the shipped students
REPLAY_TARGET_S = 300.0  # docs/design.md §11: 100 routes with 3 agents in <= 5 min on 2 cores


def replay_figure(run: Path, workers: int, agents: tuple[str, ...] = REPLAY_AGENTS) -> dict:
    """The bench's replay figure: wall time [s] of replaying every route of ``run`` with
    ``agents`` on ``workers`` processes (start-up of the workers included), into a
    temporary folder that is removed afterwards."""
    import tempfile
    import time
    jobs = plan_replay(run, list(agents), None)
    with tempfile.TemporaryDirectory(prefix="replay-bench-") as tmp:
        t0 = time.perf_counter()
        replay(run, list(agents), Path(tmp), workers=workers, progress=False)
        wall = time.perf_counter() - t0
    from harness.common.npz import read_npz
    ticks = 0
    for j in jobs:
        ticks += len(read_npz(Path(j.log), "log", LOG_FIX, ("scene_t",))["scene_t"])
    return {"replay_wall_s": wall, "replay_routes": len(jobs), "replay_agents": len(agents), "replay_ticks": ticks,
            "replay_workers": workers, "replay_target_s": REPLAY_TARGET_S}
