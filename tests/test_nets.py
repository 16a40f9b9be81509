"""The committed towns: figures of docs/design.md §2.1, and reproducible rebuilds (real netconvert)."""
from __future__ import annotations

import pytest
import sumolib

import sumo_nets
from sumo_nets.stats import net_stats


@pytest.fixture(scope="module")
def stats():
    return {t: net_stats(sumo_nets.net_path(t)) for t in sumo_nets.TOWNS}


def test_town12_is_a_large_mixed_town(stats):
    s = stats["town12"]
    assert s["width_m"] >= 2000
    assert s["height_m"] >= 2000
    assert s["traffic_lights"] >= 15
    assert s["stop_junctions"] >= 10
    assert s["curved_share"] >= 0.20
    assert s["sidewalk_share"] == 1.0
    assert s["crossings"] > 0


def test_town07_is_curved_rural_without_lights(stats):
    s = stats["town07"]
    assert s["curved_share"] > 0.5
    assert s["traffic_lights"] == 0
    assert s["stop_junctions"] > 0


def test_small_towns_have_their_junction_kinds(stats):
    assert stats["town01"]["traffic_lights"] > 0
    assert stats["town02"]["junctions"].get("allway_stop", 0) > 0
    assert stats["town02"]["junctions"].get("priority_stop", 0) > 0


def test_every_town_has_sidewalks_crossings_and_no_dead_ends(stats):
    for town, s in stats.items():
        assert s["sidewalk_share"] == 1.0, town
        assert s["crossings"] > 0, town
        assert "dead_end" not in s["junctions"], town


def test_lane_widths_and_speed_limits_by_road_class():
    for town in sumo_nets.TOWNS:
        net = sumo_nets.load_net(town)
        for e in net.getEdges(withInternal=False):
            for lane in e.getLanes():
                if lane.allows("passenger"):
                    assert 3.0 <= lane.getWidth() <= 3.5, lane.getID()
                    assert round(lane.getSpeed() * 3.6) in (30, 50, 60), lane.getID()


@pytest.mark.parametrize("town", list(sumo_nets.TOWNS))
def test_rebuild_is_byte_identical_to_the_committed_net(town, tmp_path):
    first = sumo_nets.build(town, out_dir=tmp_path / "a")
    second = sumo_nets.build(town, out_dir=tmp_path / "b")
    assert first.read_bytes() == second.read_bytes()
    assert first.read_bytes() == sumo_nets.net_path(town).read_bytes(), \
        f"committed {town} is stale: run 'sumo-scimm nets build --town {town}'"


def test_another_seed_moves_the_junctions(tmp_path):
    """The seed reaches the geometry, not only the file's header (which names the seed)."""
    nodes = {}
    for seed in (1, 2):
        net = sumolib.net.readNet(str(sumo_nets.build("town01", seed=seed, out_dir=tmp_path / str(seed))))
        nodes[seed] = {n.getID(): n.getCoord() for n in net.getNodes()}
    assert nodes[1].keys() == nodes[2].keys()  # the same junctions...
    assert any(nodes[1][k] != nodes[2][k] for k in nodes[1])  # ...some of them elsewhere
