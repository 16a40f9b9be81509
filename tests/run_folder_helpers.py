"""Helpers of the run-folder and bad-input tests (test_run_folder.py, test_write_errors.py,
test_bad_input.py): the smoke commands, running the CLI in-process, and checks of a run
folder's files; a route file of one smoke route (tests of whole pipelines whose barely
trained students stand until the route's timeout, about 10 s of wall time a route)."""
from __future__ import annotations

import contextlib
import csv
import io
import json
import os
from pathlib import Path

from harness.common.lock import LOCK_NAME
from sumo_scimm.cli import main


ROOT = Path(__file__).resolve().parents[1]
SMOKE_ONE = ["eval", "--routes", "town12_smoke", "--routes-subset", "0", "--agent", "route_follower",
             "--workers", "1"]
SMOKE_TWO = [*SMOKE_ONE[:4], "0-1", *SMOKE_ONE[5:]]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def one_smoke_route(folder: Path, route_id: str = "3", name: str | None = None) -> Path:
    """FOLDER/<name>.xml (default smoke<id>): scenarios/town12_smoke.xml with route
    ``route_id`` only."""
    import re
    text = (ROOT / "scenarios" / "town12_smoke.xml").read_text()
    head, rest = text.split("\n", 2)[:2], text.split("\n", 2)[2]
    route = re.search(rf'  <route id="{route_id}" .*?</route>\n', rest, re.S)[0]
    path = folder / f"{name or f'smoke{route_id}'}.xml"
    path.write_text("\n".join(head) + "\n" + route + "</routes>\n")
    return path


def finished_run(factory, argv: list[str]) -> Path:
    """A finished ``eval`` of ``argv`` (e.g. SMOKE_ONE) in a fresh folder of pytest's
    ``tmp_path_factory``, for a module's tests to copy and damage."""
    out = factory.mktemp("run") / "run"
    code, printed = _cli([*argv, "--out", str(out)])
    assert code == 0, printed
    return out


def tree(folder: Path) -> dict[str, bytes]:
    """{relative path: bytes} of every file under ``folder``: to check a refusal left it as it was."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _cli(argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        code = main(argv)
    return code, buf.getvalue()


def _one_line_exit_2(code: int, printed: str, *words: str) -> str:
    lines = [ln for ln in printed.splitlines() if ln.strip()]
    assert code == 2, printed
    assert len(lines) == 1, printed
    assert lines[0].startswith("sumo-scimm: error: "), printed
    assert "Traceback" not in printed
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def _records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]


def _leftovers(out: Path) -> list[Path]:
    """Temporary files and lock files left in a folder tree."""
    return [p for p in out.rglob("*") if p.name.endswith((".tmp", ".tmp.npz")) or p.name == LOCK_NAME]


def _consistent(out: Path) -> list[str]:
    """records.jsonl, records.csv and results.json list the same route runs; returns them."""
    keys = [r["key"] for r in _records(out)]
    with open(out / "records.csv", newline="") as f:
        assert sorted(r["key"] for r in csv.DictReader(f)) == sorted(keys)
    data = json.loads((out / "results.json").read_text())
    assert len(data["_checkpoint"]["records"]) == len(keys)
    return keys


def _without_wall_clock(rec: dict) -> dict:
    rec = dict(rec)
    rec.pop("wall_time")
    rec["lb"] = {**rec["lb"], "meta": {**rec["lb"]["meta"], "duration_system": None}}
    return rec
