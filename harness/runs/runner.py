"""The evaluation runner: routes fan out over worker processes, one libsumo each (docs/design.md §10).

Outputs in the run folder:

    records.jsonl   one JSON record per route run, appended and flushed as each ends
    records.csv     the same as a table, rewritten (atomically) after every route
    workers.jsonl   per route run: the worker process (host, pid), how many routes it has
                    run, and its resident memory after this one [MB] (the soak figure)
    logs/<route>_rep<k>.npz   the per-tick event log of that run (harness.loop.episode.EpisodeLog)

    run.jsonc       what the run is (the software, harness.runs.provenance; every route run's
                    key, seed, route, agent, agent config and its digest, rules, step
                    deadline), written when it starts (a finished run scored again by
                    ``resume`` keeps the one it has); not named *.json, so Bench2Drive's
                    merge_route_json.py, which reads every *.json of a folder, reads only
                    results.json (a folder's older ``run.json`` is renamed by ``resume``)
    b2d/<save_name>/metric_info.json   under ``--rules b2d``: Bench2Drive's per-tick ego
                    state of that run (harness.scoring.bench2drive)
    results.json    the Leaderboard results file (``--checkpoint``): while routes are left,
                    "Started" without a global record, as the leaderboard writes it

Every route run gets its own seed, derived from the run seed, the route's place in its set
and the repetition (harness.runs.evaluate, harness.runs.jobs.route_seed), so records do not depend on the number of workers or the
backend. A worker that dies (kill -9, segfault) has its route recorded as "Failed -
Simulation crashed" with the reason; a new worker takes over and the run goes on. A worker
whose agent call (construction, setup, sensors, run_step, destroy) runs KILL_AFTER s past
its deadline (``--agent-timeout``) is killed by the parent (harness.runs.workers) and its
route recorded as "Failed - Agent crashed" (the agent timed out), whatever the agent did
with the alarm.
``resume`` keeps the complete records already in ``records.jsonl`` and runs only the rest
(a torn last line is dropped and redone); it refuses (BadInput) a folder whose run.jsonc
differs from the resumed run's (other options, another checkpoint; other software when
records would be added), or whose records are not route runs of it, so a run's scores
never mix records of two runs.

An output that cannot be written (a full disk, a read-only or forbidden folder) stops the
run with an OSError naming the file, wherever it happens (a worker writing a route's log,
the parent appending a record): it is never a route's record, so the route runs again
when the run is resumed. A record line cut short by a full disk is removed again.

Backends: ``local`` (spawned worker processes, each running routes one after another) and
``ray`` (harness.runs.ray_backend: each route a Ray task in a fresh process); both stream the
records into the same files in completion order.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from files.atomic import signals_held, write_atomic
from harness.common.errors import BadInput
from harness.common.lock import check_folder, folder_identity, open_nofollow
from harness.common.progress import progress
from harness.runs.jobs import Job, crash_record, hung_record, release_freed_memory, run_job_safely, worker_stats
from harness.runs.workers import HUNG, run_workers
from harness.scoring.records import parse_record, record_line
from harness.runs.provenance import OLD_RUN_FILE, RUN_FILE, check_same_run, run_identity


_routes_run = 0  # routes this worker process has run (its workers.jsonl lines)


def _eval_task(job: Job) -> tuple[dict, dict]:
    """In a worker: the route's record and the worker's stats after it."""
    global _routes_run
    rec = run_job_safely(job)
    _routes_run += 1
    release_freed_memory()  # before the memory sample: what the worker holds, not its peak
    return rec, worker_stats(_routes_run)


def _append(f, line: str, path: Path, sync: bool = False) -> None:
    """Append ``line`` to the unbuffered binary file ``f`` (of ``path``), whole or not at
    all: if a write fails (a full disk), what it wrote is cut off again and the OSError
    names ``path``. ``sync``: fsync'ed before returning."""
    data = memoryview(line.encode())
    start = os.fstat(f.fileno()).st_size
    try:
        done = 0
        while done < len(data):
            done += f.write(data[done:])
        if sync:
            os.fsync(f.fileno())
    except OSError as exc:
        try:
            os.ftruncate(f.fileno(), start)
        except OSError:
            pass
        if exc.errno is None:
            raise
        raise OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(path)) from exc


_DAMAGED = "the file is damaged; delete that line"
_AFRESH = "or start the run afresh in another --out"


def read_records(path: Path, check: bool = False) -> list[dict]:
    """Complete records of a records.jsonl (a torn last line, one without its newline, is
    ignored). ``check``: every other line must be a route record as ``eval`` writes it
    (harness.scoring.validate.record_line_problem: its fields, each of its type and in
    its range, no key twice, its Leaderboard record as the scorer reads it) and the only
    one of its route run, else BadInput naming the line; without it such lines are
    skipped."""
    return [rec for _, rec in _numbered_records(path, check)]


def _numbered_records(path: Path, check: bool = False) -> list[tuple[int, dict]]:
    """read_records with each record's line number (1-based)."""
    from harness.scoring.validate import DuplicateKey, no_duplicates, record_line_problem
    out: list[tuple[int, dict]] = []
    if not path.exists():
        return out
    lines = path.read_text(errors="replace").split("\n")
    seen: dict[str, int] = {}  # key -> its line
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            rec = parse_record(line, no_duplicates)
            bad = record_line_problem(rec) if check else None
        except (json.JSONDecodeError, DuplicateKey, RecursionError) as exc:
            if i == len(lines) - 1:  # torn: cut short while it was written
                continue
            bad = f"is not a JSON record ({exc})"
        if check and not bad and rec["key"] in seen:
            raise BadInput(f"{path} line {i + 1} repeats the record of route run {rec['key']} of line "
                           f"{seen[rec['key']]}: {_DAMAGED} (line {seen[rec['key']]} keeps the route run), {_AFRESH}")
        if bad and check:
            raise BadInput(f"{path} line {i + 1} {bad}: {_DAMAGED} (its route runs again on --resume), {_AFRESH}")
        if not bad and isinstance(rec, dict) and "key" in rec:
            if check:
                seen[rec["key"]] = i + 1
            out.append((i + 1, rec))
    return out


def check_route_runs(path: Path, numbered: list[tuple[int, dict]], jobs: list[Job]) -> None:
    """BadInput naming the first line of records.jsonl (``path``; ``numbered``: its records
    with their line numbers) that is not a route run of ``jobs`` (the run's job list, as
    run.jsonc has it): another key, another seed or another place in the run (its
    Leaderboard record's index)."""
    by_key = {j.key: j for j in jobs}
    for n, rec in numbered:
        job = by_key.get(rec["key"])
        if job is None:
            raise BadInput(f"{path} line {n} is a record of route run {str(rec['key'])[:40]}, which is not in this "
                           f"run (its {RUN_FILE}): {_DAMAGED}, {_AFRESH}")
        lb_index = rec["lb"]["index"] if isinstance(rec.get("lb"), dict) else None
        what = (f"has seed {rec.get('seed')}, the run's {job.key} has seed {job.seed}" if rec.get("seed") != job.seed
                else f"has Leaderboard index {lb_index}, the run's {job.key} has index {job.index}"
                if lb_index != job.index else None)
        if what:
            raise BadInput(f"{path} line {n} {what}: {_DAMAGED} (its route runs again on --resume), {_AFRESH}")


def _keep_complete_lines(path: Path, resume: bool, check: bool = False, keys: set | None = None) -> list[dict]:
    """Start a JSON-lines file afresh, or (resume) keep its complete lines (``keys``: only
    those of these route runs); replaced atomically, so nothing is lost meanwhile, and
    appends start on a fresh line."""
    kept = read_records(path, check) if resume else []
    if keys is not None:
        kept = [r for r in kept if isinstance(r["key"], str) and r["key"] in keys]
    write_atomic(path, "".join(record_line(r) for r in kept))
    return kept


def _run_local(jobs: list[Job], workers: int, emit) -> None:
    """Run jobs on ``workers`` spawned processes (harness.runs.workers); ``emit(job, record,
    stats)`` as each ends (stats None when the worker died or was killed: a hung agent's
    route is "Failed - Agent crashed", harness.runs.jobs.hung_record)."""
    def lost(job: Job, reason, caller) -> None:
        emit(job, hung_record(job) if reason == HUNG else
             crash_record(job, f"worker process died (exit code {reason})"), None)

    run_workers(jobs, workers, _eval_task, lambda job, out: emit(job, *out), lost)


def check_results_file(checkpoint: Path, jobs: list[Job], resume: bool) -> None:
    """BadInput if the results file ``checkpoint`` exists and is not this run's to write:
    a fresh run never replaces one; a resumed run only one whose records are all route
    runs of it."""
    if not checkpoint.is_file() or checkpoint.stat().st_size == 0:
        return
    fix = "give another --checkpoint (or --out), or remove the file"
    if not resume:
        raise BadInput(f"--checkpoint {checkpoint} already holds a results file of another run: {fix}")
    try:
        records = json.loads(checkpoint.read_text())["_checkpoint"]["records"]
        ids = {r["route_id"] for r in records}
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise BadInput(f"--checkpoint {checkpoint} is not a results file ({type(exc).__name__}): {fix}") from None
    ours = {f"RouteScenario_{j.key}" for j in jobs}
    other = sorted(str(i) for i in ids - ours)
    if other:
        raise BadInput(f"--checkpoint {checkpoint} holds route {other[0][:40]}, not a route run of this run: "
                       f"{fix}")


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
    numbered = _numbered_records(out / "records.jsonl", check=True) if resume else []
    kept = [rec for _, rec in numbered]
    adding = not resume or bool({j.key for j in jobs} - {r["key"] for r in kept})
    if resume:  # before Ray starts: a refused resume starts nothing
        check_same_run(out, identity, kept, adding)
        check_route_runs(out / "records.jsonl", numbered, jobs)
    check_results_file(checkpoint or out / "results.json", jobs, resume)
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
        old = out / OLD_RUN_FILE  # a folder of an older sumo-scimm: the file under its new name
        if old.is_file() and not (out / RUN_FILE).exists() and not adding:
            os.replace(old, out / RUN_FILE)
        if adding:  # a finished run scored again keeps the run.jsonc of the software that made it
            write_atomic(out / RUN_FILE, json.dumps(identity, indent=1) + "\n")
        if old.is_file():
            old.unlink()
        done = _keep_complete_lines(rec_path, resume, check=True)
        # the memory samples of the routes kept (a route run again gets a new one)
        _keep_complete_lines(workers_path, resume, keys={r["key"] for r in done})
        here = folder_identity(out)  # the run's folder, checked before each write
        jobs = [dataclasses.replace(j, folder=here) for j in jobs]
        have = {r["key"] for r in done}
        todo = [j for j in jobs if j.key not in have]
        records = list(done)
        bar = progress(total=len(jobs), initial=len(jobs) - len(todo), desc="eval", unit="route",
                       show=show_progress)
        append = os.O_WRONLY | os.O_APPEND
        with (open(open_nofollow(rec_path, append), "ab", buffering=0) as f,
              open(open_nofollow(workers_path, append), "ab", buffering=0) as wf):
            def emit(job: Job, rec: dict, stats: dict | None) -> None:
                check_folder(out, here)
                with signals_held():  # the route's lines and the rewritten tables, all or none
                    _append(f, record_line(rec), rec_path, sync=True)
                    records.append(rec)
                    if stats is not None:
                        _append(wf, json.dumps({"key": job.key, **stats}) + "\n", workers_path)
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
    check_folder(out, here)
    with signals_held():
        write_outputs(records, len(jobs), out, checkpoint, sensors, finished=len(records) == len(jobs))
    return records


def _worker_samples(path: Path) -> tuple[list[dict], int]:
    """The memory samples of a workers.jsonl, and how many of its lines are not one (not
    JSON, or without a whole ``pid`` and ``routes``, a finite ``rss_mb`` >= 0, a text or
    no ``host``); a torn last line is not counted."""
    rows, skipped = [], 0
    try:
        lines = path.read_text(errors="replace").split("\n")
    except OSError:
        return rows, 0
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
        except (ValueError, RecursionError):
            skipped += i != len(lines) - 1  # the last one: torn while it was written
            continue
        def whole(v) -> bool:
            return isinstance(v, int) and not isinstance(v, bool) and v >= 0
        mb = r.get("rss_mb") if isinstance(r, dict) else None
        if (isinstance(r, dict) and whole(r.get("pid")) and whole(r.get("routes"))
                and isinstance(mb, (int, float)) and not isinstance(mb, bool) and math.isfinite(mb) and mb >= 0
                and isinstance(r.get("host"), (str, type(None)))):
            rows.append(r)
        else:
            skipped += 1
    return rows, skipped


def rss_summary(out: Path) -> dict | None:
    """Worker memory over a run, from its workers.jsonl: for each worker process, the
    resident memory after its first and after its last route [MB]. ``growth_mb`` is the
    largest last - first over the workers, ``slope_mb_per_100`` the largest least-squares
    trend (MB per 100 routes) of a worker that ran >= 3 routes; None without samples.
    The file is a side file: a damaged line is left out (``skipped_lines``, and a note on
    stderr), never an error."""
    path = out / "workers.jsonl"
    rows, skipped = _worker_samples(path) if path.exists() else ([], 0)
    if skipped:
        print(f"note: {path}: {skipped} damaged line{'s' if skipped > 1 else ''} left out of the worker memory "
              "figures", file=sys.stderr)
    by_worker: dict[tuple, list[tuple[int, float]]] = {}
    for r in rows:
        by_worker.setdefault((r.get("host"), r["pid"]), []).append((r["routes"], float(r["rss_mb"])))
    if not by_worker:
        return None
    growth, slope = [], []
    for samples in by_worker.values():
        samples.sort()
        growth.append(samples[-1][1] - samples[0][1])
        if len(samples) >= 3:
            n, mb = np.array(samples, dtype=float).T
            slope.append(float(np.polyfit(n, mb, 1)[0]) * 100)
    summary = {"routes": len(rows), "workers": len(by_worker),
               "max_routes_per_worker": max(len(s) for s in by_worker.values()),
               "first_mb": max(s[0][1] for s in by_worker.values()),
               "peak_mb": max(mb for s in by_worker.values() for _, mb in s),
               "growth_mb": round(max(growth), 1),
               "slope_mb_per_100": round(max(slope), 2) if slope else float("nan")}
    if skipped:
        summary["skipped_lines"] = skipped
    return summary
