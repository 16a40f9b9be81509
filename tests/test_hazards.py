"""The hazard actors: one class per hazard type behind one interface, chosen by
``make_hazard`` from the route file's type name (no simulation is started here)."""
from __future__ import annotations

import numpy as np
import pytest

from harness.sim.hazard_actor import HazardActor
from harness.sim.hazards import HAZARD_ACTORS, TIMEOUT_HAZARDS, make_hazard
from harness.sim.plan import build_plan
from scenarios import SETS, set_path
from scenarios.hazards import HAZARDS
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
    assert set(TIMEOUT_HAZARDS) == {"ParkedObstacle", "SignalizedJunction", "UnprotectedLeftTurn"}


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
