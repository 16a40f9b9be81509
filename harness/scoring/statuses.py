"""Route statuses of the CARLA Leaderboard 2.0 (its statistics_manager.py), in one table.

An episode ends with one of the texts of ``STATUSES`` (``EpisodeResult.status``):

| status | ended by | infraction it adds | crash |
| --- | --- | --- | --- |
| Completed | RouteCompletion | - | no |
| Failed - Agent timed out | RouteTimeout | route_timeout | no |
| Failed - Agent deviated from the route | InRoute | route_dev | no |
| Failed - Agent got blocked | Blocked | vehicle_blocked | no |
| Failed - Agent crashed | an agent error, a non-finite control, the step deadline | - | yes |
| Failed - Simulation crashed | a simulator or harness error, a dead worker | - | yes |
| Failed - Agent couldn't be set up | an error in the agent's set-up or sensors | - | yes |

A route-ending criterion (harness.scoring.criteria) adds its infraction
(harness.scoring.infractions.detect); a crash adds none, and its message reaches the route
record as the caller's crash message (``crash_message``). The route record's status is
recomputed from the infraction lists as the Leaderboard does
(harness.scoring.scores.route_status): "Perfect" (RC 100, no infraction), "Completed"
(RC 100), else "Failed - <message>" or plain "Failed".
"""
from __future__ import annotations

from dataclasses import dataclass

PERFECT = "Perfect"
COMPLETED = "Completed"
FAILED = "Failed"
FAILED_TIMEOUT = "Failed - Agent timed out"
FAILED_DEVIATION = "Failed - Agent deviated from the route"
FAILED_BLOCKED = "Failed - Agent got blocked"
FAILED_AGENT = "Failed - Agent crashed"
FAILED_SIMULATION = "Failed - Simulation crashed"
FAILED_SETUP = "Failed - Agent couldn't be set up"
_PREFIX = f"{FAILED} - "


def failed(message: str) -> str:
    """The Leaderboard's failure status: "Failed - <message>", or "Failed" without one."""
    return f"{_PREFIX}{message}" if message else FAILED


@dataclass(frozen=True)
class Status:
    """How an episode ended: its status text, the infraction the ending adds (key in the
    Leaderboard's results and message, ``{at}`` standing for the ego's location text), and
    whether it was a crash (an error, not a route-ending criterion)."""

    text: str
    infraction: str = ""
    infraction_message: str = ""
    crash: bool = False

    @property
    def message(self) -> str:
        """The failure message of the status text ("Agent crashed"), "" for a success."""
        return self.text.removeprefix(_PREFIX) if self.text.startswith(_PREFIX) else ""


# The rows with an infraction are in the Leaderboard's order of precedence for the
# status of a route record: when several of their infractions are present, the last wins.
STATUSES: dict[str, Status] = {s.text: s for s in (
    Status(COMPLETED),
    Status(FAILED_TIMEOUT, "route_timeout", "Route timeout."),
    Status(FAILED_DEVIATION, "route_dev", "Agent deviated from the route at {at}"),
    Status(FAILED_BLOCKED, "vehicle_blocked", "Agent got blocked at {at}"),
    Status(FAILED_AGENT, crash=True),
    Status(FAILED_SIMULATION, crash=True),
    Status(FAILED_SETUP, crash=True),
)}
ENDING_INFRACTIONS = tuple(s for s in STATUSES.values() if s.infraction)  # in order of precedence


def crash_message(status: str) -> str:
    """The failure message of a crash status, as the Leaderboard passes it to the route
    record's status ("Agent crashed"); "" for any other status."""
    s = STATUSES.get(status)
    return s.message if s is not None and s.crash else ""


def ended_by_criterion(status: str) -> bool:
    """Whether the episode ended normally: completed, or ended by a route-ending
    criterion; False for a crash."""
    s = STATUSES.get(status)
    return s is not None and not s.crash
