"""The committed route sets: docs/design.md §2.2 figures, reproducible rebuilds, disjointness,
and route lengths against SUMO's own driving distance (real libsumo)."""
from __future__ import annotations

from collections import Counter

import libsumo
import pytest

import sumo_nets
from sumo_scimm.cli import main
from scenarios import SETS, set_path
from scenarios.check import check_file, check_route
from scenarios.hazards import HAZARDS
from scenarios.make import make_set
from scenarios.routefile import read_routes, write_routes


def test_town12_short_matches_the_spec(short_routes):
    assert len(short_routes) == 100
    per_type = Counter()
    for r in short_routes:
        assert r.town == "town12"
        assert 270.0 <= check_route(r).length <= 330.0, r.id
        assert len(r.hazards) >= 1, r.id
        per_type.update({h.type for h in r.hazards})
    assert set(per_type) == set(HAZARDS)
    assert min(per_type.values()) >= 8, per_type


def test_smoke_covers_light_stop_pedestrian_obstacle():
    _, routes = read_routes(set_path("town12_smoke"))
    assert len(routes) == 4
    kinds = {h.type for r in routes for h in r.hazards}
    assert {"SignalizedJunction", "StopSignJunction", "PedestrianCrossing", "ParkedObstacle"} <= kinds


def test_training_sets_span_all_towns():
    _, routes = read_routes(set_path("train"))
    assert {r.town for r in routes} == set(sumo_nets.TOWNS)


@pytest.mark.parametrize("name", list(SETS))
def test_committed_sets_pass_check(name):
    n, problems = check_file(set_path(name))
    assert problems == []
    assert n == sum(k for _, k in SETS[name].towns)


@pytest.mark.parametrize("name", list(SETS))
def test_rebuild_is_byte_identical_to_the_committed_set(name, tmp_path):
    spec = SETS[name]
    meta = {"set": name, "seed": str(spec.seed), "min_length": f"{spec.length[0]:g}",
            "max_length": f"{spec.length[1]:g}"}
    out = write_routes(tmp_path / f"{name}.xml", meta, make_set(name))
    assert out.read_bytes() == set_path(name).read_bytes(), \
        f"committed {name} is stale: run 'sumo-scimm routes make --set {name}'"


def test_another_seed_gives_other_routes():
    a = make_set("town12_smoke", seed=1)
    b = make_set("town12_smoke", seed=2)
    assert [r.edges for r in a] != [r.edges for r in b]


def _ends(name):
    return {(r.edges[0], r.edges[-1]) for r in read_routes(set_path(name))[1]}


def test_no_training_or_validation_route_shares_start_and_end_with_evaluation():
    short = _ends("town12_short")
    assert not (_ends("train") & short)
    assert not (_ends("val") & short)
    assert not (_ends("val") & _ends("train"))


@pytest.mark.parametrize("other", ["town12_short", "train", "val"])
def test_second_evaluation_set_shares_no_start_and_end_with_another_set(other):
    second = _ends("town12_second")
    assert len(second) == 100  # its own routes are distinct too
    assert not (second & _ends(other))


def test_second_evaluation_set_follows_town12_short_recipe_with_another_seed():
    short, second = SETS["town12_short"], SETS["town12_second"]
    assert (second.towns, second.length, second.target) == (short.towns, short.length, short.target)
    assert second.seed not in {s.seed for n, s in SETS.items() if n != "town12_second"}


def test_route_lengths_agree_with_sumo_driving_distance(short_routes):
    """Our length (lane and junction-internal shapes, lane changes blended) against the
    distance SUMO itself reports along the same edges. Tolerance 2 % (6 m): SUMO measures
    on the lane its vehicle picked, we on ours; on curves inner and outer lanes differ by
    lane offset x heading change (3.5 m x 1.5 rad ~ 5 m)."""
    libsumo.start(["sumo", "-n", str(sumo_nets.net_path("town12")), "--step-length", "0.05",
                   "--no-step-log", "--no-warnings"])
    try:
        compared = 0
        for r in short_routes[:40]:
            libsumo.route.add(f"r{r.id}", list(r.edges))
            libsumo.vehicle.add(f"v{r.id}", f"r{r.id}", departPos=str(r.depart_pos),
                                departLane="best", departSpeed="0")
            libsumo.simulationStep()
            v = f"v{r.id}"
            dist = libsumo.vehicle.getDrivingDistance(v, r.edges[-1], r.arrival_pos)
            dist += libsumo.vehicle.getLanePosition(v) - r.depart_pos  # moved during the step
            libsumo.vehicle.remove(v)
            if abs(dist) > 1e6:  # SUMO's INVALID_DOUBLE: no answer for this vehicle
                continue
            compared += 1
            assert check_route(r).length == pytest.approx(dist, abs=0.02 * dist), r.id
        assert compared >= 35
    finally:
        libsumo.close()


def test_routes_make_help_names_every_buildable_set(capsys):
    with pytest.raises(SystemExit):
        main(["routes", "make", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert f"set name ({', '.join(SETS)})" in shown
