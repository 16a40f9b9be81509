"""What besides a run's options decides its records: the software (docs/reliability.md).

``software()`` names the code of the stages (a digest of their Python sources, route sets,
nets and shipped checkpoints), the Python version and the versions of the libraries that
run inside the closed loop. ``run.jsonc`` (RUN_FILE) keeps it beside the route runs, with a digest of
each agent's config file and, for an agent given as ``module:Class``, of its module file;
``--resume`` refuses to add records to a folder started with other software (harness.runs.runner),
so the records of one run never mix two versions of the experiment: a new commit, another
libsumo or another ONNX Runtime gives other trajectories (measured for the runtime:
docs/reliability.md).

Strict on purpose: any change to a ``.py`` file of the stages counts, even one that cannot
change a record (a docstring, the bench). Left out: the CPU type (records depend on it too,
but a Ray run spans machines; a run finished on another CPU type is another sample of the
experiment, compared by its means; ``machine()`` names it in a student's manifest and in
the bench's figures); the software of Ray nodes other than the driver's (the
driver's is recorded, the nodes are expected to run the same install); and the libraries
outside the loop (pandas, tqdm, matplotlib)."""
from __future__ import annotations

import hashlib
import importlib.metadata
import importlib.util
import json
import os
import platform
from functools import lru_cache
from pathlib import Path

from harness.common.errors import BadInput

# what the run is, in its folder; not named *.json, so that a tool reading every *.json of a
# folder as a results file (Bench2Drive's merge_route_json.py) reads results.json alone
RUN_FILE = "run.jsonc"
OLD_RUN_FILE = "run.json"  # its name in run folders made before
# the stages (docs/design.md §1) and the files in them that can change a record
PACKAGES = ("files", "scenarios", "sumo_nets", "controller", "harness", "scimm", "model", "sumo_scimm")
SUFFIXES = (".py", ".xml", ".pt")
# the distributions whose code runs inside the loop, the scoring or the student's export
LIBRARIES = ("libsumo", "sumolib", "numpy", "scipy", "opencv-python-headless", "torch", "onnxruntime", "onnx",
             "numba")


def _package_dir(name: str) -> Path:
    spec = importlib.util.find_spec(name)  # found, not imported: model would pull torch
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(f"package {name} not found: reinstall sumo-scimm (make setup)")
    return Path(next(iter(spec.submodule_search_locations)))


def code_digest() -> str:
    """sha256 (first 16 hex digits) over the relative path and bytes of every source, route
    set, net and checkpoint file of the stages, in path order."""
    h = hashlib.sha256()
    for name in PACKAGES:
        root = _package_dir(name)
        files = sorted(p for p in root.rglob("*")
                       if p.suffix in SUFFIXES and "__pycache__" not in p.parts and p.is_file())
        for p in files:
            h.update(f"{name}/{p.relative_to(root).as_posix()}\0".encode())
            h.update(p.read_bytes())
            h.update(b"\0")
    return h.hexdigest()[:16]


@lru_cache(maxsize=1)
def software() -> dict:
    """{"code": digest, "python": version, <library>: version, ...}: computed once per process."""
    out = {"code": code_digest(), "python": platform.python_version()}
    for lib in LIBRARIES:
        try:
            out[lib] = importlib.metadata.version(lib)
        except importlib.metadata.PackageNotFoundError:
            out[lib] = None
    return out


def cpu_of(cpuinfo: str) -> dict:
    """The CPU described by the text of Linux's ``/proc/cpuinfo``: {"cpu": model name,
    "cpu_id": "family/model/stepping" (decimal, as the kernel prints them; None where it
    prints none), "simd": the widest vector extension its flags list, "AVX-512", "AVX2" or
    "other"}. A virtual machine may report a bare name ("AMD EPYC"); the id tells CPU
    generations apart, and the vector extension picks the kernels of NumPy, ONNX Runtime and
    torch (docs/reliability.md, "On the same CPU model")."""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            break  # the first processor's block describes them all
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    ident = [fields.get(k) for k in ("cpu family", "model", "stepping")]
    flags = set(fields.get("flags", "").split())
    return {"cpu": fields.get("model name") or platform.processor() or platform.machine(),
            "cpu_id": "/".join(ident) if all(ident) else None,
            "simd": "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "other"}


@lru_cache(maxsize=1)
def machine() -> dict:
    """``cpu_of`` the CPU the process runs on (read from /proc/cpuinfo on Linux; elsewhere
    the platform's processor name and no id), and "cores": the CPUs the OS offers. Kept in
    a student's manifest: the data and the student's last bits depend on the CPU, so the
    records of a run made on several machines say which seed came from which."""
    try:
        with open("/proc/cpuinfo") as f:
            found = cpu_of(f.read())
    except OSError:  # not Linux
        found = cpu_of("")
    return {**found, "cores": os.cpu_count()}


def config_digest(path: str) -> str | None:
    """sha256 (first 16 hex digits) of a file's bytes (an agent's checkpoint or module),
    None if it cannot be read (the agent check reports that). Read once per process while
    the file stays the same file, unchanged (inode, size, change times)."""
    try:
        st = os.stat(path)
        return _digest(path, (st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns))
    except OSError:
        return None


@lru_cache(maxsize=16)
def _digest(path: str, stamp: tuple) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]  # an OSError is not cached


def _agent_module(agent: str) -> str | None:
    """The file of a ``module:Class`` agent's module (outside the stages' digest), else None."""
    if ":" not in agent:
        return None
    try:
        spec = importlib.util.find_spec(agent.partition(":")[0])
    except (ImportError, ValueError):
        return None
    return spec.origin if spec is not None and spec.origin and os.path.isfile(spec.origin) else None


def run_identity(jobs) -> dict:
    """What makes the records of ``jobs`` (harness.runs.jobs.Job) what they are: the software,
    and per route run key the seed, the route (a hash of its parsed definition), the agent
    (and, for ``module:Class``, its module file's digest), its config (an absolute path) and
    the config's digest, the rules, the step deadline, whether it records a dataset and the
    ego model (controller.ego).
    Workers, backend and the results file do not change records and are not in it."""
    def config(path):
        return os.path.abspath(path) if path else None
    runs = {}
    for j in jobs:
        run = {"seed": j.seed, "route": hashlib.sha256(repr(j.route).encode()).hexdigest()[:16],
               "agent": j.agent, "agent_config": config(j.agent_config),
               "agent_config_digest": config_digest(config(j.agent_config)) if j.agent_config else None,
               "rules": j.rules, "agent_timeout": j.agent_timeout, "collect": bool(j.collect_dir),
               "vehicle": j.vehicle}
        module = _agent_module(j.agent)
        if module:
            run["agent_module_digest"] = config_digest(module)
        runs[j.key] = run
    return {"software": software(), "route_runs": runs}


def run_file(out: Path) -> Path:
    """The file saying what the run in folder ``out`` is: RUN_FILE, or OLD_RUN_FILE in a
    folder that has only that."""
    new, old = out / RUN_FILE, out / OLD_RUN_FILE
    return old if not new.exists() and old.exists() else new


def check_same_run(out: Path, identity: dict, done: list[dict], adding: bool) -> None:
    """BadInput unless the run being resumed in ``out`` is the one described by ``identity``:
    the same route runs (its run.jsonc, or run.json; a folder from before either: every record one of
    them, with its seed) and, if it holds records and route runs are left (``adding``), the
    same software. A finished run may be scored again by other software (no record is added
    to it), and a run without a record yet may start again with it (none would mix)."""
    fix = "resume with the options the run was started with, or choose another --out"
    afresh = f"start the run afresh (remove {out}, or choose another --out)"
    unknown = (f"{out} was started by a sumo-scimm that did not record its software, so its records may "
               f"come from other code: {afresh}")
    mixing = adding and bool(done)
    path = run_file(out)
    if not path.exists():
        if mixing:
            raise BadInput(unknown)
        for rec in done:
            job = identity["route_runs"].get(rec["key"])
            if job is None or job["seed"] != rec.get("seed"):
                what = "is not a route run of this run" if job is None else f"has seed {rec.get('seed')}, not {job['seed']}"
                raise BadInput(f"{out}: record {rec['key']} {what}: {fix}")
        return
    try:
        old = json.loads(path.read_text())
    except (ValueError, RecursionError, OSError):  # ValueError: JSONDecodeError, UnicodeDecodeError
        raise BadInput(f"{path} is not a JSON file: {fix}") from None
    new_runs = identity["route_runs"]
    if isinstance(old, dict) and "software" in old:
        if not isinstance(old["software"], dict):
            raise BadInput(f"{path} is damaged (its software entry is not a table): {afresh}")
        if mixing and old["software"] != identity["software"]:
            raise BadInput(f"{out} was started with other software ({_difference(old['software'], identity['software'])}); "
                           f"its records would mix two versions: resume with the software it was started with, or {afresh}")
        old_runs = old.get("route_runs")
        _check_vehicle(out, path, old_runs, new_runs, afresh)
    else:  # an older layout: the route runs alone, without their configs' digests or ego model
        if mixing:
            raise BadInput(unknown)
        _check_vehicle(out, path, old, new_runs, afresh)
        old_runs = ({k: {f: v for f, v in r.items() if f != "vehicle"} if isinstance(r, dict) else r
                     for k, r in old.items()} if isinstance(old, dict) else old)
        new_runs = {k: {f: v for f, v in r.items() if not f.endswith("_digest") and f != "vehicle"}
                    for k, r in new_runs.items()}
    if old_runs != new_runs:
        other = (f", or the same run described by other software ({_difference(old['software'], identity['software'])})"
                 if isinstance(old, dict) and old.get("software", identity["software"]) != identity["software"] else "")
        raise BadInput(f"{out} holds another run ({_first_difference(old_runs, new_runs)}){other}: {fix}")


def _difference(was: dict, now: dict) -> str:
    """'<name> <now>, the run has <was>' for the first software entry that differs."""
    name = next(k for k in (*now, *was) if now.get(k) != was.get(k))
    return f"{name} {now.get(name)}, the run has {was.get(name)}"


def _check_vehicle(out: Path, path: Path, old_runs, new_runs: dict, afresh: str) -> None:
    """BadInput if the run in ``out`` was driven with another ego model (its route runs name
    it; a run.jsonc made before they did fails the comparison of the route runs instead), or
    if its run file ``path`` names one that is not a text (the file is damaged)."""
    for key, r in (old_runs.items() if isinstance(old_runs, dict) else ()):
        if isinstance(r, dict) and "vehicle" in r and not isinstance(r["vehicle"], str):
            raise BadInput(f"{path} is damaged (route_runs.{str(key)[:40]}.vehicle is {str(r['vehicle'])[:40]}, not "
                           f"the name of an ego model): {afresh}")
    was = sorted({r["vehicle"] for r in old_runs.values() if isinstance(r, dict) and "vehicle" in r}
                 if isinstance(old_runs, dict) else ())
    now = sorted({r["vehicle"] for r in new_runs.values()})
    if was and was != now:
        raise BadInput(f"{out} was driven with --vehicle {', '.join(was)}, not {', '.join(now)}: resume with "
                       f"--vehicle {was[0]}, or choose another --out")


def _first_difference(old: dict, new: dict) -> str:
    """One phrase naming how route runs ``new`` differ from ``old`` (both non-equal)."""
    if not isinstance(old, dict) or set(old) != set(new):
        only = sorted(set(new) - set(old if isinstance(old, dict) else {}))
        return f"route runs differ{': ' + ', '.join(only[:3]) + ' not in it' if only else ''}"
    for key in new:
        was, now = old[key], new[key]
        if was != now:
            if not isinstance(was, dict):
                return f"{key} differs"
            f = next(f for f in (*now, *was) if was.get(f) != now.get(f))
            if f == "seed" and now.get("route") == was.get("route"):  # route_seed: --seed and the route's place
                return f"{key}: seed {now.get(f)!r}, the run has {was.get(f)!r}: another --seed than the run's"
            return f"{key}: {f} {now.get(f)!r}, the run has {was.get(f)!r}"
    return "it differs"
