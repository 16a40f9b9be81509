"""The evaluation and collection stages as functions: a route set in, a run folder out
(SPEC §3, §5, §10). ``sumo-scimm eval`` and ``collect`` call them, and so does
``sumo-scimm reproduce``; every check of the user's input happens before a route runs and
raises ``BadInput`` with one line naming the problem and the fix.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from harness.common.errors import BadInput
from harness.loop.agent import check_agent, load_agent
from harness.loop.episode import AGENT_TIMEOUT
from harness.runs.jobs import Job, route_seed


@dataclass(frozen=True)
class Backend:
    """Where route runs go: ``local`` worker processes or ``ray`` tasks (``address``: the
    Ray cluster to join; None starts a local Ray); ``workers``: None for every core."""

    workers: int | None = None
    name: str = "local"
    address: str | None = None

    def check(self) -> None:
        """BadInput unless the numbers make sense and Ray is installed if asked for."""
        if self.workers is not None and self.workers < 1:
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


def select_routes(spec: str | None, ids: list[str]) -> list[str]:
    """Route ids selected by --routes-subset: "3", "0-9", "1,4,7" or a mix (None: all)."""
    if not spec:
        return ids
    chosen: list[str] = []
    for part in spec.split(","):
        part = part.strip()
        if "-" in part and all(p.strip().isdigit() for p in part.split("-", 1)):
            a, b = (int(p) for p in part.split("-", 1))
            chosen += [i for i in ids if i.isdigit() and a <= int(i) <= b]
        elif part in ids:
            chosen.append(part)
        else:
            raise BadInput(f"--routes-subset: no route {part!r} in the set")
    return [i for i in ids if i in set(chosen)]


def _route_set(name: str) -> Path:
    """The checked route file of a set name or path."""
    from scenarios import resolve_set
    from scenarios.check import check_file
    path = resolve_set(name)
    _, problems = check_file(path)
    if problems:
        raise BadInput(f"{path}: {problems[0]} (run 'sumo-scimm routes check {path}')")
    return path


def _fresh_or_resumed(out: Path, resume: bool, what: str) -> None:
    if not resume and (out / "records.jsonl").exists() and (out / "records.jsonl").stat().st_size:
        raise BadInput(f"{out} already holds {what}: add --resume to finish it, or choose another --out")


def _run(jobs: list[Job], out: Path, resume: bool, backend: Backend, **kwargs) -> list[dict]:
    """harness.runs.runner.run_eval on the chosen backend; a Ray that cannot be reached is bad input."""
    from harness.runs.ray_backend import BackendError
    from harness.runs.runner import run_eval
    try:
        return run_eval(jobs, out, backend.workers, resume, backend=backend.name, address=backend.address,
                        **kwargs)
    except BackendError as exc:
        raise BadInput(str(exc)) from None


def evaluate(routes: str, agent: str, agent_config: str | None = None, out: Path | None = None, *,
             subset: str | None = None, repetitions: int = 1, seed: int = 0, resume: bool = False,
             checkpoint: Path | None = None, rules: str = "lb2.0", agent_timeout: float = AGENT_TIMEOUT,
             backend: Backend = Backend()) -> EvalResult:
    """Drive route set ``routes`` (a set name or a route file) with ``agent`` and score it.

    ``out`` defaults to ``runs/<set>_<agent>``; ``checkpoint`` (the Leaderboard results file)
    to ``out/results.json``. A route's seed depends on the run seed, the repetition and its
    place in the whole set (not the subset), so ``subset`` reruns a route exactly as the full
    run drove it. ``resume`` finishes an interrupted run in ``out``.
    """
    if repetitions < 1:
        raise BadInput(f"--repetitions {repetitions}: must be >= 1")
    if not (math.isfinite(agent_timeout) and agent_timeout > 0):
        raise BadInput(f"--agent-timeout {agent_timeout}: must be a positive number of seconds")
    backend.check()
    from scenarios.routefile import read_routes
    path = _route_set(routes)
    agent, agent_config = check_agent(agent, agent_config)
    _, all_routes = read_routes(path)
    keep = set(select_routes(subset, [r.id for r in all_routes]))
    chosen = [r for r in all_routes if r.id in keep]
    if not chosen:
        raise BadInput(f"--routes-subset {subset!r} selects no route of {path.name}")
    out = out if out is not None else Path("runs") / f"{path.stem}_{agent.replace(':', '.')}"
    _fresh_or_resumed(out, resume, "a run")
    place = {r.id: i for i, r in enumerate(all_routes)}
    runs = [(rep, r) for rep in range(repetitions) for r in chosen]
    jobs = [Job(k, r, rep, agent, agent_config, route_seed(seed, rep * len(all_routes) + place[r.id]),
                str(out / "logs"), rules, agent_timeout=agent_timeout) for k, (rep, r) in enumerate(runs)]
    checkpoint = checkpoint if checkpoint is not None else out / "results.json"
    sensors = [s["type"] for s in load_agent(agent).sensors()]
    records = _run(jobs, out, resume, backend, checkpoint=checkpoint, sensors=sensors)
    from harness.runs.runner import rss_summary
    g = json.loads(checkpoint.read_text())["_checkpoint"]["global_record"]
    return EvalResult(out, records, g, rss_summary(out))


def collect(routes: str, out: Path, *, repetitions: int = 1, seed: int = 0, resume: bool = False,
            backend: Backend = Backend()):
    """The expert drives route set ``routes`` and every episode is recorded at 4 Hz into
    ``out/episodes`` (harness.expert.collect); returns the frame index it writes to
    ``out/index.csv`` (a pandas DataFrame, harness.expert.dataset.build_index)."""
    if repetitions < 1:
        raise BadInput(f"--repetitions {repetitions}: must be >= 1")
    backend.check()
    from harness.expert.dataset import build_index
    from scenarios.routefile import read_routes
    path = _route_set(routes).resolve()
    _fresh_or_resumed(out, resume, "a collection")
    _, chosen = read_routes(path)
    runs = [(rep, r) for rep in range(repetitions) for r in chosen]
    jobs = [Job(k, r, rep, "expert", None, route_seed(seed, k), str(out / "logs"),
                collect_dir=str(out / "episodes"), route_file=str(path)) for k, (rep, r) in enumerate(runs)]
    _run(jobs, out, resume, backend, sensors=["pose", "speed", "world"])
    return build_index(out)
