"""The bench's bare-libsumo reference steps the traffic the harness stepped: the
replay of a logged ego through ``harness.loop.episode.Scene`` reproduces the episode's traffic,
and its check tells another traffic apart; a call between steps is timed apart from SUMO.
Real libsumo; no performance figure is asserted."""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from sumo_scimm.bench import closed_loop
from sumo_scimm.bench.closed_loop import _bare_step_ms
from harness.loop.episode import run_episode
from scenarios import set_path
from scenarios.routefile import read_routes

SMOKE = read_routes(set_path("town12_smoke"))[1]


def test_the_replay_reproduces_the_episode_traffic_and_tells_another_seed_apart(monkeypatch):
    route, seed = SMOKE[1], 7  # background vehicles on its roads near the ego on most ticks
    res = run_episode(route, "route_follower", None, seed)
    bg = res.log.columns["bg_speed"]
    assert sum(not math.isnan(v) for v in bg) > len(bg) // 2  # the check has speeds to compare
    ms, same, between_ms = _bare_step_ms(route, seed, res.log)
    assert same, "the bare replay drove other traffic than the episode"
    assert ms > 0.0
    assert math.isnan(between_ms)  # nothing ran between the steps
    _, same_other, _ = _bare_step_ms(route, seed + 1, res.log)  # another seed: other traffic
    assert not same_other
    # with a call between steps: its own time is returned per tick, apart from SUMO's. A
    # clock that only the call moves (by 5 ms) makes both figures exact: 5 ms a tick for the
    # call, none of it in SUMO's figure; the traffic is still the episode's (the call cannot
    # reach SUMO)
    clock, calls = [0.0], []

    def between():
        calls.append(1)
        clock[0] += 0.005
    monkeypatch.setattr(closed_loop, "time", SimpleNamespace(perf_counter=lambda: clock[0]))
    ms, same, between_ms = _bare_step_ms(route, seed, res.log, between=between)
    assert same, "with a call between the steps, the replay drove other traffic"
    assert ms == 0.0
    assert between_ms == pytest.approx(5.0, rel=1e-9)  # sums of 5 ms differences of a float clock
    assert len(calls) == len(bg)
