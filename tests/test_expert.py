"""The expert in closed loop on real libsumo: routes of town12_short whose situations (below,
docs/expert.md) lead to a collision or a red light unless the expert and the harness handle them."""
from __future__ import annotations

import json

import pytest

from sumo_scimm.cli import main

# route id -> the situation that makes it hard (docs/expert.md)
HARD_ROUTES = {
    "13": "waiting at the line to turn left: going on yellow lets its rear cross on red",
    "17": "a crossing walker moved by moveToXY, whose speed SUMO reports as 0",
    "50": "the hard-braking leader: SUMO can insert it late, beside the ego",
    "63": "the route changes lanes on an edge, into the lane of a vehicle coming from behind",
    "68": "a vehicle cutting in from the curb, which looks like parallel traffic",
}
# routes where the expert, driving CARLA's car (the default ego), still collides: the
# car's brakes build up over 1/6 s and give 7 m/s^2 (controller.carla_car), and the
# cut-in's gap is then too short; the kinematic car, braking harder at once, misses it
COLLIDES_WITH_CARLA_CAR = {"68"}


@pytest.mark.slow
def test_the_expert_drives_its_hard_routes_without_red_light_and_collides_only_on_the_known_cut_in(tmp_path, capsys):
    """Every hard route completed, no red light run, no collision but the one known cut-in
    (COLLIDES_WITH_CARLA_CAR), where exactly one vehicle collision is expected: a second one,
    or one on any other route, fails."""
    out = tmp_path / "run"
    subset = ",".join(HARD_ROUTES)
    assert main(["eval", "--routes", "town12_short", "--routes-subset", subset, "--agent", "expert",
                 "--workers", "2", "--out", str(out)]) == 0
    records = [json.loads(line) for line in (out / "records.jsonl").read_text().splitlines()]
    assert sorted(r["route_id"] for r in records) == sorted(HARD_ROUTES)
    for r in records:
        assert r["status"] == "Completed", (r["route_id"], r["message"])
        bad = {k: v for k, v in r["lb"]["infractions"].items()
               if v and k.startswith(("collisions", "red_light"))}
        if r["route_id"] in COLLIDES_WITH_CARLA_CAR:
            assert set(bad) == {"collisions_vehicle"} and len(bad["collisions_vehicle"]) == 1, bad
        else:
            assert bad == {}, f"route {r['route_id']} ({HARD_ROUTES[r['route_id']]}): {bad}"
