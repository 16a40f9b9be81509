"""The route status table (harness.scoring.statuses) and what reads it: the crash message
of a record, the infraction a route-ending criterion adds, the status of a route record."""
from __future__ import annotations

from harness.scoring.infractions import KEYS
from harness.scoring.scores import route_status
from harness.scoring.statuses import (COMPLETED, FAILED_AGENT, FAILED_BLOCKED, FAILED_DEVIATION, FAILED_SETUP,
                                      FAILED_SIMULATION, FAILED_TIMEOUT, STATUSES, crash_message,
                                      ended_by_criterion, failed)


def inf(**lists):
    return {k: list(lists.get(k, [])) for k in KEYS}


def test_the_table_holds_the_leaderboard_texts():
    assert set(STATUSES) == {"Completed", "Failed - Agent deviated from the route", "Failed - Agent got blocked",
                             "Failed - Agent timed out", "Failed - Agent crashed", "Failed - Simulation crashed",
                             "Failed - Agent couldn't be set up"}
    assert failed("Agent crashed") == FAILED_AGENT
    assert failed("") == "Failed"
    assert STATUSES[FAILED_SETUP].message == "Agent couldn't be set up"
    assert STATUSES[COMPLETED].message == ""


def test_crashes_carry_their_message_the_criteria_an_infraction():
    assert {s for s in STATUSES if crash_message(s)} == {FAILED_AGENT, FAILED_SIMULATION, FAILED_SETUP}
    assert crash_message(FAILED_SIMULATION) == "Simulation crashed"
    assert crash_message(FAILED_BLOCKED) == ""
    assert crash_message("not a status") == ""
    assert {s.text: s.infraction for s in STATUSES.values() if s.infraction} == {
        FAILED_DEVIATION: "route_dev", FAILED_BLOCKED: "vehicle_blocked", FAILED_TIMEOUT: "route_timeout"}
    assert all(s.infraction in KEYS for s in STATUSES.values() if s.infraction)
    assert [s for s in STATUSES if ended_by_criterion(s)] == [COMPLETED, FAILED_TIMEOUT, FAILED_DEVIATION,
                                                              FAILED_BLOCKED]


def test_a_record_status_takes_blocked_over_deviation_over_timeout_over_a_crash():
    dev = ["Agent deviated from the route at (x=1.0, y=1.0, z=0.0)"]
    blocked = ["Agent got blocked at (x=1.0, y=1.0, z=0.0)"]
    timeout = ["Route timeout."]
    assert route_status(10.0, inf(route_timeout=timeout, route_dev=dev, vehicle_blocked=blocked),
                        "Agent crashed") == FAILED_BLOCKED
    assert route_status(10.0, inf(route_timeout=timeout, route_dev=dev), "Agent crashed") == FAILED_DEVIATION
    assert route_status(10.0, inf(route_timeout=timeout), "Agent crashed") == FAILED_TIMEOUT
