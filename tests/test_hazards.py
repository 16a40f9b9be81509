"""The hazard registry and the hazard actors: one ``HazardType`` per type
(scenarios.hazards.HAZARDS) and one actor class per type behind one interface, chosen by
``make_hazard`` from the route file's type name (no simulation is started here)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from harness.sim.hazard_actor import HazardActor
from harness.scoring.infractions import scenario_timeouts
from harness.sim.hazards import HAZARD_ACTORS, actor, make_hazard
from harness.sim.plan import build_plan
from scenarios import SETS, set_path
from scenarios import hazards as scenario_hazards
from scenarios.hazards import HAZARDS, HazardType, Param, Site, check_params, find_sites
from scenarios.make import _draw
from scenarios.routefile import Hazard, read_routes
from sumo_nets import load_net


def test_every_hazard_type_has_its_actor_class_and_no_other():
    assert set(HAZARD_ACTORS) == set(HAZARDS)
    for name, cls in HAZARD_ACTORS.items():
        assert issubclass(cls, HazardActor)
        assert cls.__name__ == name


@pytest.mark.parametrize("name", SETS)
def test_every_hazard_of_the_committed_sets_has_an_actor_class(name):
    _, routes = read_routes(set_path(name))
    assert {h.type for r in routes for h in r.hazards} <= set(HAZARD_ACTORS)


def test_the_scenario_timeout_applies_to_the_hazards_that_can_block_the_ego():
    # Leaderboard 2.0: obstacles, a red light and an unprotected left turn can hold the ego
    assert {k for k, h in HAZARDS.items() if h.timeout} == {"ParkedObstacle", "SignalizedJunction",
                                                            "UnprotectedLeftTurn"}


def test_make_hazard_builds_each_hazard_of_a_route_as_its_type(short_routes):
    route = next(r for r in short_routes if len({h.type for h in r.hazards}) >= 2)
    net = load_net(route.town)
    plan = build_plan(route, net)
    rng = np.random.default_rng(0)
    for k, h in enumerate(route.hazards):
        actor = make_hazard(h, plan, net, rng, k)
        assert type(actor) is HAZARD_ACTORS[h.type]
        assert actor.tag == f"hz{k}"
        assert not actor.started
        trigger_s, _ = plan.path.project(*h.trigger[:2])
        assert actor.trigger_s == trigger_s
        assert actor.site_s == trigger_s + float(h.params["distance"])
        assert not actor.timeout_active(actor.site_s, 0.0)  # not started yet
        assert actor.walking() == {}


def test_only_a_parked_obstacle_keeps_the_route_bubble_away(short_routes):
    """The bubble spawns nothing from 100 m before to 150 m past an obstacle."""
    for route in short_routes[:10]:
        net = load_net(route.town)
        plan = build_plan(route, net)
        for k, h in enumerate(route.hazards):
            actor = make_hazard(h, plan, net, np.random.default_rng(0), k)
            span = actor.quiet_span()
            if h.type == "ParkedObstacle":
                assert span == (actor.site_s - 100.0, actor.site_s + 150.0)
            else:
                assert span is None


def test_an_unknown_hazard_type_is_refused_by_name(short_routes):
    route = short_routes[0]
    net = load_net(route.town)
    plan = build_plan(route, net)
    bad = Hazard("Meteor_1", "Meteor", route.hazards[0].trigger, {"distance": "20"})
    with pytest.raises(ValueError, match="'Meteor'"):
        make_hazard(bad, plan, net, np.random.default_rng(0), 0)


def test_a_new_hazard_type_is_one_registry_entry_and_one_actor_class(short_routes, monkeypatch):
    """A type added as one ``HazardType`` (scenario stage) and one ``@actor`` class
    (simulation stage) is validated, found on a route, drawn by the builder, timed out
    and built, with no other change anywhere."""
    debris = HazardType("Debris", "ConstructionObstacle", "debris on the road", (
        Param("distance", "float", 10, 50), Param("pieces", "int", 1, 5)),
        lambda net, path: [Site("Debris", 50.0, 60.0)], (20, 30),
        lambda rng, p: p | {"pieces": str(int(rng.integers(1, 6)))}, timeout=True)
    monkeypatch.setitem(HAZARDS, "Debris", debris)  # the scenario stage's one entry
    monkeypatch.setitem(HAZARD_ACTORS, "Debris", None)  # (removed again after the test)

    @actor
    class Debris(HazardActor):  # the simulation stage's one entry
        pass

    assert check_params("Debris", {"distance": "20", "pieces": "3"}) is None
    assert check_params("Debris", {"distance": "20", "pieces": "9"}) == "Debris: pieces=9 is outside [1, 5]"
    route = short_routes[0]
    net = load_net(route.town)
    plan = build_plan(route, net)
    assert Site("Debris", 50.0, 60.0) in find_sites(net, plan.path)
    s, params = _draw("Debris", Site("Debris", 50.0, 60.0), plan.path, np.random.default_rng(0))
    assert 50.0 <= s <= 60.0 and check_params("Debris", params) is None
    hazard = Hazard("Debris_1", "Debris", route.hazards[0].trigger, params)
    built = make_hazard(hazard, plan, net, np.random.default_rng(0), 0)
    assert type(built) is Debris
    built.started = True
    assert built.timeout_active(built.site_s - 1.0, 10.0)
    stood = {"route_index": np.full(301, float(np.searchsorted(plan.s, 50.0))),  # 300 s at route s = 50 m
             "t": np.arange(301.0)}
    assert scenario_timeouts(stood, plan, [("Debris", 10.0, 60.0, {})]) == ["Agent timed out a scenario"]


def test_the_scoring_reads_timeouts_and_two_ways_from_the_registry(short_routes):
    """An ego standing 300 s at route s = 50 m, past the trigger (10 m) and short of the
    site (60 m), times out a hazard only if its type's entry says so (Leaderboard:
    SCENARIO_TIMEOUT 240 s); only a ParkedObstacle bypassed through the oncoming lane is a
    TwoWays scenario."""
    assert {k for k, h in HAZARDS.items() if h.two_ways} == {"ParkedObstacle"}
    assert scenario_hazards.two_ways("ParkedObstacle", {"bypass": "oncoming"})
    assert not scenario_hazards.two_ways("ParkedObstacle", {"bypass": "neighbour"})
    route = short_routes[0]
    plan = build_plan(route, load_net(route.town))
    stood = {"route_index": np.full(301, float(np.searchsorted(plan.s, 50.0))), "t": np.arange(301.0)}
    for kind, h in HAZARDS.items():
        out = scenario_timeouts(stood, plan, [(kind, 10.0, 60.0, {})])
        assert out == (["Agent timed out a scenario"] if h.timeout else [])


def _stood(s: float, seconds: int) -> tuple[dict, SimpleNamespace]:
    """An ego standing at route s [m] (a 1 m dense plan, s = index) for ``seconds`` s, 1 s rows."""
    plan = SimpleNamespace(s=np.arange(101.0))
    return {"route_index": np.full(seconds + 1, s), "t": np.arange(seconds + 1.0)}, plan


def test_a_scenario_times_out_after_more_than_240_s():
    """Trigger at s = 10 m, site at 60 m, the ego standing at 50 m from t = 0: 240 s is not
    more than 240 s; 241 s (the log's last row) is."""
    span = [("ParkedObstacle", 10.0, 60.0, {})]
    assert scenario_timeouts(*_stood(50.0, 240), span) == []
    assert scenario_timeouts(*_stood(50.0, 241), span) == ["Agent timed out a scenario"]


def test_a_scenario_ends_10_m_past_its_site():
    """Site at 60 m: standing 300 s at 69 m, the scenario still runs (times out); at 70 m it
    ended at t = 0 (no time out)."""
    span = [("ParkedObstacle", 10.0, 60.0, {})]
    assert scenario_timeouts(*_stood(69.0, 300), span) == ["Agent timed out a scenario"]
    assert scenario_timeouts(*_stood(70.0, 300), span) == []


def test_timeout_active_runs_240_s_from_the_trigger_up_to_10_m_past_the_site():
    """A ParkedObstacle triggered at s = 20 m at t = 5 s, site 30 m further (50 m): running
    at 245.0 s (240 s after) and not at 245.05; running at s = 59.9 m and not at 60.0 m.
    (A fake plan whose projection is x itself; no simulation.)"""
    plan = SimpleNamespace(path=SimpleNamespace(project=lambda x, y: (x, 0.0)))
    h = Hazard("ParkedObstacle_1", "ParkedObstacle", (20.0, 0.0, 0.0, 0.0), {"distance": "30"})
    built = HazardActor(h, plan, None, np.random.default_rng(0), 0)
    assert (built.trigger_s, built.site_s) == (20.0, 50.0)
    built.update(19.0, 4.0, 5.0)
    assert not built.started
    built.update(20.0, 5.0, 5.0)  # the trigger: started, t0 = 5 s
    assert built.timeout_active(49.0, 245.0)
    assert not built.timeout_active(49.0, 245.05)
    assert built.timeout_active(59.9, 10.0)
    assert not built.timeout_active(60.0, 10.0)
