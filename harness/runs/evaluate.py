"""The evaluation and collection stages as functions: a route set in, a run folder out
(docs/design.md §3, §5, §10). ``sumo-scimm eval`` and ``collect`` call them, and so does
``sumo-scimm reproduce``; every check of the user's input happens before a route runs and
raises ``BadInput`` with one line naming the problem and the fix.

A run holds its folder for its whole length (harness.common.lock: a second ``eval``,
``collect`` or ``--resume`` on it is refused); before the first route the folder, its
``logs`` (and ``episodes``) folder and the results file are checked writable, and a
results file of another run is never replaced (harness.runs.runner.check_results_file). The agent is
built once for its checks (harness.loop.agent.check_agent_setup, on the first route's
plan); ``--workers`` is bounded by the cores (``check_workers``). A file that
cannot be written later (a full disk) stops the run with one line naming it
(``BadInput``); the routes recorded so far are kept and ``--resume`` finishes the run.
"""
from __future__ import annotations

import dataclasses
import errno
import json
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from controller.ego import DEFAULT_VEHICLE
from harness.common.errors import BadInput
from harness.common.lock import FolderLock
from harness.loop.agent import check_agent_setup
from harness.loop.deadline import AGENT_TIMEOUT
from harness.runs.jobs import Job, route_seed


# Route runs in one run (repetitions x routes) [-]: the job list and run.jsonc grow with it
# (run.jsonc by about 230 bytes a run); 100,000 runs of town12_short are about 18 h of
# driving on 2 cores (500 in 323 s, docs/reliability.md).
MAX_ROUTE_RUNS = 100_000
_MAX_ID_DIGITS = 9  # a --routes-subset bound with more digits names no route of a set


WORKERS_PER_CORE = 2  # local worker processes per core, at most: each holds a libsumo (~400 MB)


def check_agent_timeout(timeout: float) -> None:
    """BadInput unless ``timeout`` (--agent-timeout) is a positive number of seconds."""
    if not (math.isfinite(timeout) and timeout > 0):
        raise BadInput(f"--agent-timeout {timeout}: must be a positive number of seconds")


def check_workers(workers: int | None) -> None:
    """BadInput unless ``workers`` (local processes; None: one per core) is between 1 and
    WORKERS_PER_CORE per core of this computer."""
    cores = os.cpu_count() or 1
    if workers is None:
        return
    if workers < 1:
        raise BadInput(f"--workers {_clip(str(workers))}: must be >= 1")
    if workers > WORKERS_PER_CORE * cores:
        raise BadInput(f"--workers {_clip(str(workers))}: at most {WORKERS_PER_CORE * cores} ({WORKERS_PER_CORE} per "
                       f"core, {cores} cores; each worker holds a simulator of about 400 MB); give fewer")


@dataclass(frozen=True)
class Backend:
    """Where route runs go: ``local`` worker processes or ``ray`` tasks (``address``: the
    Ray cluster to join; None starts a local Ray); ``workers``: None for every core."""

    workers: int | None = None
    name: str = "local"
    address: str | None = None

    def check(self) -> None:
        """BadInput unless the numbers make sense and Ray is installed if asked for."""
        if self.name == "local":
            check_workers(self.workers)
        elif self.workers is not None and self.workers < 1:
            raise BadInput(f"--workers {self.workers}: must be >= 1")
        if self.address and self.name != "ray":
            raise BadInput("--address needs --backend ray")
        if self.name == "ray":
            from harness.runs.ray_backend import BackendError, check_available
            try:
                check_available()
            except BackendError as exc:
                raise BadInput(str(exc)) from None


@dataclass(frozen=True)
class EvalResult:
    """A finished (or resumed) evaluation: its folder, records and Leaderboard global record."""

    out: Path
    records: list[dict]
    global_record: dict
    memory: dict | None  # worker memory over the run (harness.runs.runner.rss_summary)

    def statuses(self) -> dict[str, int]:
        """Route runs per Leaderboard status."""
        counts: dict[str, int] = {}
        for r in self.records:
            counts[r["status"]] = counts.get(r["status"], 0) + 1
        return dict(sorted(counts.items()))


def _clip(text: str, width: int = 16) -> str:
    """``text`` for a message: cut to ``width`` characters, saying how long it was."""
    return text if len(text) <= width else f"{text[:width]}... ({len(text)} characters)"


def select_routes(spec: str | None, ids: list[str]) -> list[str]:
    """Route ids selected by --routes-subset: "3", "0-9", "1,4,7" or a mix (None: all).
    Every part must select a route of the set: an id not in it, a range without one (or
    reversed) and an empty subset are BadInput."""
    if spec is None:
        return ids
    if not spec.strip(" ,"):
        raise BadInput(f"--routes-subset {spec!r} names no route: give ids such as '3', '0-9' or '1,4,7', "
                       "or leave the option out to run every route")
    chosen: list[str] = []
    for part in spec.split(","):
        part = part.strip()
        bounds = [p.strip() for p in part.split("-", 1)]
        if "-" in part and all(p.isdigit() and len(p) <= _MAX_ID_DIGITS for p in bounds):
            a, b = int(bounds[0]), int(bounds[1])
            if a > b:
                raise BadInput(f"--routes-subset: range {part!r} is reversed (write {b}-{a})")
            hit = [i for i in ids if i.isdigit() and a <= int(i) <= b]
            if not hit:
                raise BadInput(f"--routes-subset: range {part!r} holds no route of the set")
            chosen += hit
        elif part in ids:
            chosen.append(part)
        else:
            raise BadInput(f"--routes-subset: no route {_clip(part)!r} in the set")
    return [i for i in ids if i in set(chosen)]


def _check_count(repetitions: int, routes: int | None = None) -> None:
    """BadInput unless ``repetitions`` (and, given the number of routes, the route runs)
    is between 1 and MAX_ROUTE_RUNS."""
    if repetitions < 1:
        raise BadInput(f"--repetitions {_clip(str(repetitions))}: must be >= 1")
    runs = repetitions * (routes or 1)
    if runs > MAX_ROUTE_RUNS:
        what = f"{repetitions} x {routes} routes = {runs} route runs" if routes else f"{_clip(str(repetitions))}"
        raise BadInput(f"--repetitions {what}: at most {MAX_ROUTE_RUNS} route runs in one run; use fewer "
                       "repetitions, or several runs with other --seed and --out")


def _known_lengths(routes: list) -> list:
    """The routes, each with its length: one whose file gives none gets its traced length
    (a route that fails before it is driven is recorded with it; results.json holds
    numbers only)."""
    from scenarios.check import check_route
    return [r if math.isfinite(r.length) else dataclasses.replace(r, length=round(check_route(r).length, 2))
            for r in routes]


def first_plan(route):
    """The plan of ``route`` (harness.sim.plan.GlobalPlan), on which the agent's checks
    run a route's set-up calls."""
    from harness.sim.plan import build_plan
    from sumo_nets import load_net
    return build_plan(route, load_net(route.town))


def _route_set(name: str) -> Path:
    """The checked route file of a set name or path."""
    from scenarios import resolve_set
    from scenarios.check import check_file, problem_line
    path = resolve_set(name)
    _, problems = check_file(path)
    if problems:
        raise BadInput(f"{problem_line(path, problems[0])} (run 'sumo-scimm routes check {path}')")
    return path


def _fresh_or_resumed(out: Path, resume: bool, what: str) -> None:
    if not resume and (out / "records.jsonl").exists() and (out / "records.jsonl").stat().st_size:
        raise BadInput(f"{out} already holds {what}: add --resume to finish it, or choose another --out")


def _probe(folder: Path, what: str) -> None:
    """BadInput unless a file can be created in ``folder`` (tried: a permission check would
    pass for root on a read-only file system)."""
    try:
        fd, name = tempfile.mkstemp(prefix=".write-check-", dir=folder)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise BadInput(f"{what} {folder}: cannot write there ({exc.strerror or exc}); make it writable, "
                       "or choose another folder") from None


def check_writable(out: Path, folders: list[Path], checkpoint: Path | None = None) -> None:
    """BadInput unless the run folder ``out``, its output ``folders`` (the ones that exist;
    the others are made in ``out``) and the results file ``checkpoint`` can be written."""
    _probe(out, "run folder")
    for d in folders:
        if d.exists():
            if not d.is_dir():
                raise BadInput(f"{d} is not a folder: remove it, or choose another --out")
            _probe(d, "output folder")
    if checkpoint is not None:
        if checkpoint.exists() and not checkpoint.is_file():
            raise BadInput(f"--checkpoint {checkpoint} is not a file: give a file path")
        if not checkpoint.parent.is_dir():
            raise BadInput(f"--checkpoint {checkpoint}: its folder does not exist; create it, or give another path")
        if checkpoint.exists() and not os.access(checkpoint, os.W_OK):
            raise BadInput(f"--checkpoint {checkpoint} is read-only: make it writable, or give another path")
        _probe(checkpoint.parent, "--checkpoint folder")


def stopped_by(exc: OSError, resume_hint: bool = True) -> BadInput:
    """The one line for an output that could not be written while a run ran."""
    path = exc.filename or "an output file"
    fix = {errno.ENOSPC: "free some space", errno.EDQUOT: "free some space",
           errno.EROFS: "make it writable"}.get(exc.errno, "make it writable" if exc.errno in (
               errno.EACCES, errno.EPERM) else "check the path")
    then = ", then repeat the command with --resume to finish the run" if resume_hint else ""
    return BadInput(f"cannot write {path} ({exc.strerror or exc}): the run stopped; {fix}{then}")


def _run(jobs: list[Job], out: Path, resume: bool, backend: Backend, what: str, **kwargs) -> list[dict]:
    """harness.runs.runner.run_eval on the chosen backend, in the folder ``out`` its caller
    holds (FolderLock): a fresh run on a folder that holds records, an unwritable output,
    a Ray that cannot be reached, or a file that cannot be written while it runs, is BadInput."""
    from harness.runs.ray_backend import BackendError
    from harness.runs.runner import run_eval
    _fresh_or_resumed(out, resume, what)
    folders = sorted({Path(j.log_dir) for j in jobs} | {Path(j.collect_dir) for j in jobs if j.collect_dir})
    check_writable(out, folders, kwargs.get("checkpoint"))
    try:
        return run_eval(jobs, out, backend.workers, resume, backend=backend.name, address=backend.address,
                        **kwargs)
    except BackendError as exc:
        raise BadInput(str(exc)) from None
    except OSError as exc:
        raise stopped_by(exc) from None


def evaluate(routes: str, agent: str, agent_config: str | None = None, out: Path | None = None, *,
             subset: str | None = None, repetitions: int = 1, seed: int = 0, resume: bool = False,
             checkpoint: Path | None = None, rules: str = "lb2.0", agent_timeout: float = AGENT_TIMEOUT,
             backend: Backend = Backend(), vehicle: str = DEFAULT_VEHICLE) -> EvalResult:
    """Drive route set ``routes`` (a set name or a route file) with ``agent`` and score it.

    ``out`` defaults to ``runs/<set>_<agent>``; ``checkpoint`` (the Leaderboard results file)
    to ``out/results.json``. A route's seed depends on the run seed, the repetition and its
    place in the whole set (not the subset), so ``subset`` reruns a route exactly as the full
    run drove it. ``resume`` finishes an interrupted run in ``out``. ``vehicle``: the ego
    model (controller.ego).
    """
    _check_count(repetitions)
    check_agent_timeout(agent_timeout)
    backend.check()
    from scenarios.routefile import read_routes
    path = _route_set(routes)
    _, all_routes = read_routes(path)
    keep = set(select_routes(subset, [r.id for r in all_routes]))
    chosen = _known_lengths([r for r in all_routes if r.id in keep])
    if not chosen:
        raise BadInput(f"--routes-subset {subset!r} selects no route of {path.name}")
    agent, agent_config, specs = check_agent_setup(agent, agent_config, first_plan(chosen[0]), agent_timeout)
    _check_count(repetitions, len(chosen))
    out = out if out is not None else Path("runs") / f"{path.stem}_{agent.replace(':', '.')}"
    place = {r.id: i for i, r in enumerate(all_routes)}
    runs = [(rep, r) for rep in range(repetitions) for r in chosen]
    # the workers get absolute folders: an agent may change its process's working folder
    jobs = [Job(k, r, rep, agent, agent_config, route_seed(seed, rep * len(all_routes) + place[r.id]),
                str((out / "logs").absolute()), rules, agent_timeout=agent_timeout, vehicle=vehicle)
            for k, (rep, r) in enumerate(runs)]
    checkpoint = checkpoint if checkpoint is not None else out / "results.json"
    sensors = [s["type"] for s in specs]
    from harness.runs.runner import rss_summary
    with FolderLock(out):
        records = _run(jobs, out, resume, backend, "a run", checkpoint=checkpoint, sensors=sensors)
        g = json.loads(checkpoint.read_text())["_checkpoint"]["global_record"]
        return EvalResult(out, records, g, rss_summary(out))


def collect(routes: str, out: Path, *, repetitions: int = 1, seed: int = 0, resume: bool = False,
            backend: Backend = Backend(), vehicle: str = DEFAULT_VEHICLE):
    """The expert drives route set ``routes`` and every episode is recorded at 4 Hz into
    ``out/episodes`` (harness.expert.collect); returns the frame index it writes to
    ``out/index.csv`` (a pandas DataFrame, harness.expert.dataset.build_index)."""
    _check_count(repetitions)
    backend.check()
    from harness.expert.dataset import build_index
    from scenarios.routefile import read_routes
    path = _route_set(routes).resolve()
    chosen = _known_lengths(read_routes(path)[1])
    _check_count(repetitions, len(chosen))
    runs = [(rep, r) for rep in range(repetitions) for r in chosen]
    jobs = [Job(k, r, rep, "expert", None, route_seed(seed, k), str((out / "logs").absolute()),
                collect_dir=str((out / "episodes").absolute()), route_file=str(path), vehicle=vehicle)
            for k, (rep, r) in enumerate(runs)]
    with FolderLock(out):
        _run(jobs, out, resume, backend, "a collection", sensors=["pose", "speed", "world"])
        try:
            return build_index(out)
        except OSError as exc:
            raise stopped_by(exc, resume_hint=False) from None
