"""The expert in closed loop on real libsumo: routes of town12_short on which it once
collided or ran a light, each for a reason fixed in the expert or the harness."""
from __future__ import annotations

import json

from sumo_scimm.cli import main

# route id -> what went wrong there (docs/expert.md, session 6)
ONCE_FAILED = {
    "13": "waiting at the line to turn left, it went on yellow and its rear crossed on red",
    "17": "a crossing walker reported speed 0 (moveToXY), so the forecast ignored it",
    "50": "the hard-braking leader, inserted late by SUMO, appeared beside the ego",
    "63": "the route changes lanes on an edge, into the lane of a vehicle coming from behind",
    "68": "a vehicle cutting in from the curb, seen as parallel traffic, was ignored",
}


def test_the_expert_drives_routes_it_once_failed_without_collision_or_red_light(tmp_path, capsys):
    out = tmp_path / "run"
    subset = ",".join(ONCE_FAILED)
    assert main(["eval", "--routes", "town12_short", "--routes-subset", subset, "--agent", "expert",
                 "--workers", "2", "--out", str(out)]) == 0
    records = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    assert sorted(r["route_id"] for r in records) == sorted(ONCE_FAILED)
    for r in records:
        assert r["status"] == "Completed", (r["route_id"], r["message"])
        bad = {k: v for k, v in r["lb"]["infractions"].items()
               if v and k.startswith(("collisions", "red_light"))}
        assert bad == {}, f"route {r['route_id']} ({ONCE_FAILED[r['route_id']]}): {bad}"
