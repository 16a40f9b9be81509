"""The Ray backend of the runner (docs/design.md §10): each route run is a Ray task.

``sumo-scimm eval --backend ray [--address ADDR]``. Without ``--address`` a local Ray is
started with ``--workers`` CPUs (default: every core) and shut down at the end; with it,
the driver joins that cluster (``host:port`` of its head, ``auto``, or ``ray://host:port``
for Ray Client) and only disconnects at the end.

- One SUMO per process: a task runs in a fresh worker process (``max_calls=1``), so no
  libsumo state is ever shared between routes; it asks for 1 CPU.
- Same records as the local backend: the task runs ``harness.runs.jobs.run_job`` on the same
  Job (same seed); a task that raises is the route's "Failed - Simulation crashed" record,
  and so is a worker that dies (``max_retries=0``: never retried, as a dead local worker),
  but a task that cannot write its files (an OSError) stops the run, as a local worker does.
- Results land on the driver: the task writes its episode log (and, for ``collect``, its
  dataset episode; under b2d rules, its metric_info.json) into a temporary folder of its
  node and returns the bytes; the driver
  writes them under the run folder, so a cluster needs no shared file system.
- At most ``workers`` tasks are in flight (default: every CPU of the cluster); records
  stream back in completion order through the runner's ``emit``.

Nodes need the project installed (``pip install 'sumo-scimm[ray]'``, same version as the
driver): the task imports ``harness`` there. A cluster with token authentication
(docs/cluster.md) needs ``RAY_AUTH_MODE=token`` and the head's token on every node and on the
driver; a driver without them stops at once with one line. Each task's line in workers.jsonl
names its Ray node (``node``).
"""
from __future__ import annotations

import dataclasses
import logging
import os
import socket
import tempfile
import threading
import time
import types
from pathlib import Path

from files.atomic import write_atomic
from harness.common.lock import check_folder
from harness.loop.agent import watch_agent_calls
from harness.runs.jobs import KILL_AFTER, WATCH_EVERY, Job, b2d_dir, crash_record, run_job_safely, worker_stats

OUTPUT_KINDS = ("logs", "episodes", "b2d")  # folders of a task's files: Job.log_dir, Job.collect_dir, b2d_dir
CONNECT_TIMEOUT = 10.0  # s to reach the head node's port before ray.init (which would hang)


class BackendError(Exception):
    """Ray missing or its cluster unreachable: a user error (one line, exit 2)."""


def _ray():
    try:
        import ray
    except ImportError:
        raise BackendError("--backend ray needs the ray package: pip install 'sumo-scimm[ray]'") from None
    return ray


def check_available() -> None:
    """Raise BackendError unless ``import ray`` works."""
    _ray()


def _check_reachable(address: str) -> None:
    """A ``host:port`` or ``ray://host:port`` address must accept a TCP connection
    (``ray.init`` retries an unreachable one for ever)."""
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if not host or not port.isdigit():
        if address == "auto":
            return
        raise BackendError(f"--address {address!r}: expected host:port, ray://host:port or auto")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT).close()
    except OSError as exc:
        raise BackendError(f"--address {address!r}: no Ray cluster answers there ({exc.strerror or exc}); "
                           "start one with 'ray start --head' or check the address") from None


def _check_token(address: str) -> None:
    """A ``host:port`` cluster with token authentication that this driver cannot join (no
    token, or not the cluster's) is a user error, in one line and at once: ``ray.init``
    would retry for about 20 s, then report a failed connection. Anything else is left to
    ``ray.init``. Uses Ray 2.60's internals (pyproject bounds Ray); other names: no check."""
    ray = _ray()
    try:
        from ray._private.authentication.authentication_token_setup import ensure_token_if_auth_enabled
        from ray._raylet import GcsClient
    except ImportError:
        return
    token = "RAY_AUTH_TOKEN to what `ray get-auth-token` prints on the cluster's head (docs/cluster.md)"
    try:
        ensure_token_if_auth_enabled(None, create_token_if_missing=False)  # ray.init's first check
    except ray.exceptions.AuthenticationError:
        raise BackendError(f"--address {address!r}: RAY_AUTH_MODE=token but no auth token is set: "
                           f"set {token}") from None
    saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)  # a refusal's C++ warning: the error below says it in one line
        GcsClient(address=address)  # one attempt, about 1 s
    except ray.exceptions.AuthenticationError:
        if os.environ.get("RAY_AUTH_MODE", "").lower() == "token":
            raise BackendError(f"--address {address!r}: the Ray cluster refused the auth token (RAY_AUTH_TOKEN, "
                               f"RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token): set {token}") from None
        raise BackendError(f"--address {address!r}: the Ray cluster uses token authentication: "
                           f"set RAY_AUTH_MODE=token and {token}") from None
    except Exception:  # noqa: BLE001 - anything else is ray.init's to report
        pass
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def _watch_own_agent() -> threading.Event:
    """In a Ray worker: a thread that ends this process when an agent call runs KILL_AFTER
    s past its deadline (harness.loop.agent.agent_call), as the local backend's parent
    does; the route is then recorded as its worker's death. Set the event to stop it."""
    deadline = types.SimpleNamespace(value=0.0)
    watch_agent_calls(deadline)
    done = threading.Event()

    def watch() -> None:
        while not done.wait(WATCH_EVERY):
            if deadline.value and time.monotonic() > deadline.value + KILL_AFTER:
                os._exit(HUNG_EXIT)
    threading.Thread(target=watch, daemon=True).start()
    return done


HUNG_EXIT = 124  # exit code of a Ray worker ended because its agent hung (as timeout(1)'s)


def _run_task(job: Job) -> tuple[dict, dict, dict[str, bytes]]:
    """In a Ray worker: run the job with its files in a temporary folder; returns the
    record, the worker's stats and the files ({"logs/<name>": bytes, ...})."""
    watching = _watch_own_agent()
    with tempfile.TemporaryDirectory(prefix="sumo-scimm-") as tmp:
        folders = {kind: Path(tmp) / kind for kind in OUTPUT_KINDS}
        for d in folders.values():
            d.mkdir()
        here = dataclasses.replace(job, log_dir=str(folders["logs"]), folder=(),  # the driver checks the run folder
                                   collect_dir=str(folders["episodes"]) if job.collect_dir else "")
        try:
            rec = run_job_safely(here)
        finally:
            watching.set()
        files = {f"{kind}/{p.relative_to(d).as_posix()}": p.read_bytes() for kind, d in folders.items()
                 for p in sorted(d.rglob("*")) if p.is_file() and not p.name.endswith(".tmp.npz")}
    return rec, {**worker_stats(1), "node": _ray().get_runtime_context().get_node_id()}, files


def _write_files(job: Job, files: dict[str, bytes]) -> None:
    """Write a task's files under the job's folders (atomically, as the local backend does)."""
    folders = {"logs": job.log_dir, "episodes": job.collect_dir, "b2d": str(b2d_dir(job))}
    if job.folder:
        check_folder(Path(job.log_dir).parent, job.folder)
    for name, data in files.items():
        kind, base = name.split("/", 1)
        path = Path(folders[kind]) / base
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, data)  # a Ctrl-C or SIGTERM lands after the rename


class RayPool:
    """A connection to Ray for one run: ``run(jobs, emit)`` then ``close()``."""

    def __init__(self, address: str | None, workers: int | None):
        ray = _ray()
        self._ray = ray
        self._started = False
        if not ray.is_initialized():
            quiet = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.WARNING}
            if address:
                _check_reachable(address)
                if "://" not in address and address != "auto":
                    _check_token(address)
                try:
                    ray.init(address=address, **quiet)
                except (ConnectionError, RuntimeError, ValueError) as exc:
                    raise BackendError(f"--address {address!r}: cannot join the Ray cluster ({exc})") from None
            else:
                ray.init(num_cpus=workers or os.cpu_count() or 1, **quiet)
            self._started = True
        self.slots = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._task = ray.remote(num_cpus=1, max_calls=1, max_retries=0)(_run_task)

    def run(self, jobs: list[Job], emit) -> None:
        """Run jobs as tasks; ``emit(job, record, stats)`` as each ends (stats None when
        its worker died). Interrupted, the tasks still in flight are cancelled."""
        ray = self._ray
        pending = list(reversed(jobs))
        inflight: dict = {}  # object ref -> job
        try:
            while pending or inflight:
                while pending and len(inflight) < self.slots:
                    job = pending.pop()
                    inflight[self._task.remote(job)] = job
                ready, _ = ray.wait(list(inflight), num_returns=1)
                for ref in ready:
                    job = inflight.pop(ref)
                    try:
                        rec, stats, files = ray.get(ref)
                    except ray.exceptions.RayError as exc:
                        if isinstance(getattr(exc, "cause", None), OSError):  # its files: stops the run
                            raise exc.cause from None
                        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
                        emit(job, crash_record(job, f"worker process died ({type(exc).__name__}: {reason})"), None)
                        continue
                    _write_files(job, files)
                    emit(job, rec, stats)
        finally:
            for ref in inflight:
                ray.cancel(ref, force=True)

    def close(self) -> None:
        """Shut down the Ray this pool started (a cluster joined by address is only left)."""
        if self._started:
            self._ray.shutdown()
