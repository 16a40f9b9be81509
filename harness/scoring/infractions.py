"""Leaderboard 2.0 infraction detection from an episode log (docs/design.md §9.1).

Detection is a function of the per-tick log (ego pose and speed, contacts, the route's
light states, background speed), the route's plan and the town's lanes, run once after
the episode. It returns the Leaderboard's infraction lists: message strings in the
Leaderboard's exact formats, keyed and ordered as in its results JSON. Scores are
computed from these lists only (harness.scoring.scores), as for a CARLA results file.

SUMO stand-ins for CARLA geometry (decisions, see docs/scoring.md):
- red light: the stop line is the end of every car lane of the edge entering the
  junction, +-0.6 lane width; the light's state is the state of the route's link;
- stop sign: the ego is "affected" from 6 m before to 1 m past the end of its lane at a
  stop or all-way-stop link (4 m look-ahead plus the trigger box);
- outside lanes: the nearest car lane (junction lanes included) farther than half its
  width + 0.5 m; wrong lane: outside a junction, a nearest lane heading >= 120 deg off
  the ego's heading (the Leaderboard tracks lane changes; same outcome for a car that
  does not spin in place);
- collisions: our oriented-box contacts, classified by the other actor (vehicle,
  walker, static obstacle), then the 5 s same-actor, 5 m and 0.1 m/s rules. The parked
  car and the accident's car of a ParkedObstacle are vehicles, as in the Leaderboard's
  ParkedObstacle and Accident scenarios (``vehicle.*`` actors); a construction site and
  the harness's props are static.
"""
from __future__ import annotations

import math

import numpy as np

from controller.vehicle import LENGTH
from harness.scoring.lanes import LaneIndex
from harness.scoring.statuses import STATUSES, ended_by_criterion
from harness.sim.hazard_actor import SCENARIO_END, SCENARIO_TIMEOUT
from harness.sim.plan import GlobalPlan
from harness.sim.stop_signs import stop_history, stop_passages
from harness.sim.world import PEDESTRIAN, STATIC, VEHICLE
from scenarios.hazards import HAZARDS, two_ways
from scenarios.routefile import Route

KEYS = ("collisions_layout", "collisions_pedestrian", "collisions_vehicle", "red_light", "stop_infraction",
        "outside_route_lanes", "min_speed_infractions", "yield_emergency_vehicle_infractions",
        "scenario_timeouts", "route_dev", "vehicle_blocked", "route_timeout")

COLLISION_TIME, COLLISION_RADIUS, EPSILON = 5.0, 5.0, 0.1  # [s], [m], [m/s]
RED_LIGHT_DIST = 15.0  # lights farther than this from the ego are skipped [m]
OUTSIDE_MARGIN, WRONG_DEG = 0.5, 120.0  # [m], [deg]
MIN_SPEED_CHECKPOINTS = {"lb2.0": 4, "lb2.1": 4, "b2d": 20}
_RED = (0, 1)  # TLS_CODES indices of 'r' and 'R'
_CLASS_KEY = {VEHICLE: "collisions_vehicle", PEDESTRIAN: "collisions_pedestrian", STATIC: "collisions_layout"}
_TYPE_ID = {VEHICLE: "vehicle.sumo.car", PEDESTRIAN: "walker.pedestrian.sumo", STATIC: "static.prop.obstacle"}
OBSTACLE_VEHICLES = ("parked_car", "accident")  # ParkedObstacle variants that are cars in the Leaderboard


def loc(x: float, y: float) -> str:
    """CARLA's location text: '(x=1.234, y=5.678, z=0.0)', rounded to 3 decimals."""
    return f"(x={round(float(x), 3)}, y={round(float(y), 3)}, z=0.0)"


def hazard_spans(plan: GlobalPlan, route: Route) -> list[tuple[str, float, float, dict]]:
    """(type, trigger s, site s, params) of each hazard, route arc lengths [m]."""
    out = []
    for h in route.hazards:
        s, _ = plan.path.project(h.trigger[0], h.trigger[1])
        out.append((h.type, s, s + float(h.params["distance"]), h.params))
    return out


def scored_class(actor: str, cls: int, spans) -> tuple[int, str]:
    """The class a contact is scored as and its message's type: a ParkedObstacle's parked
    or accident car (SUMO id ``hz<n>_obstacle``, n its place among the route's hazards) is a
    vehicle, though the world gives it the static class its drivers see."""
    if cls == STATIC and actor.startswith("hz") and actor.endswith("_obstacle"):
        n = actor[2:-len("_obstacle")]
        if n.isdigit() and int(n) < len(spans):
            kind, _, _, params = spans[int(n)]
            if kind == "ParkedObstacle" and params.get("variant") in OBSTACLE_VEHICLES:
                return VEHICLE, f"vehicle.sumo.{params['variant']}"
    return cls, _TYPE_ID[cls]


def collisions(log: dict, spans=()) -> dict[str, list[str]]:
    """The three collision lists; ``spans`` (hazard_spans) names the route's obstacles."""
    out = {k: [] for k in _CLASS_KEY.values()}
    t, x, y, v = log["t"], log["x"], log["y"], log["v"]
    last_id, last_time, last_loc = None, -math.inf, None
    contacts = sorted(zip(log["contact_tick"].tolist(), log["contact_actor"].tolist(),
                          log["contact_class"].tolist()), key=lambda c: c[0])
    by_tick: dict[int, list] = {}
    for tick, actor, cls in contacts:
        by_tick.setdefault(tick, []).append((actor, cls))
    for k in range(len(t)):
        if last_id is not None and t[k] - last_time > COLLISION_TIME:
            last_id = None
        if last_loc is not None and math.hypot(x[k] - last_loc[0], y[k] - last_loc[1]) > COLLISION_RADIUS:
            last_loc = None
        for actor, cls in by_tick.get(k + 1, []):  # contact ticks count from 1, log rows from 0
            if actor == last_id or last_loc is not None or v[k] < EPSILON:
                continue
            last_id, last_time, last_loc = actor, t[k], (x[k], y[k])
            scored, type_id = scored_class(actor, cls, spans)
            out[_CLASS_KEY[scored]].append(f"Agent collided against object with type={type_id} and "
                                           f"id={actor} at {loc(x[k], y[k])}")
    return out


def _segments_intersect(p1, p2, q1, q2) -> bool:
    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    d1, d2 = cross(q1, q2, p1), cross(q1, q2, p2)
    d3, d4 = cross(p1, p2, q1), cross(p1, p2, q2)
    return (d1 * d2 < 0) and (d3 * d4 < 0)


def red_lights(log: dict, plan: GlobalPlan, net) -> list[str]:
    lights = [p for p in plan.passages if p.tls]
    out, last = [], None
    lines = []
    for p in lights:
        segs = []
        for ln in net.getEdge(p.from_edge).getLanes():
            if not ln.allows("passenger"):
                continue
            sh = np.asarray(ln.getShape(), dtype=float)[:, :2]
            fwd = (sh[-1] - sh[-2]) / max(np.hypot(*(sh[-1] - sh[-2])), 1e-9)
            n = np.array([-fwd[1], fwd[0]]) * 0.6 * ln.getWidth()
            segs.append((sh[-1] - n, sh[-1] + n, fwd))
        centre = np.mean([s[0] + s[1] for s in segs], axis=0) / 2 if segs else np.zeros(2)
        lines.append((segs, centre))
    hl = LENGTH / 2
    for k in range(len(log["t"])):
        x, y, yaw = log["x"][k], log["y"][k], log["yaw"][k]
        f = np.array([math.cos(yaw), math.sin(yaw)])
        tail = (np.array([x, y]) - 0.8 * hl * f, np.array([x, y]) - (hl + 1.0) * f)
        for j, p in enumerate(lights):
            name = f"{p.tls}:{p.link}"
            segs, centre = lines[j]
            if name == last or log["tls"][k, j] not in _RED or math.hypot(*(centre - (x, y))) > RED_LIGHT_DIST:
                continue
            for a, b, fwd in segs:
                if f @ fwd > 0 and _segments_intersect(tail[0], tail[1], a, b):
                    out.append(f"Agent ran a red light {name} at {loc(*centre)}")
                    last = name
                    break
    return out


def stop_signs(log: dict, plan: GlobalPlan) -> list[str]:
    """A stop infraction for each stop-sign passage the ego reached and left without
    stopping in its zone (harness.sim.stop_signs, the state the BEV draws from too)."""
    passages = stop_passages(plan)
    if not passages or len(log["v"]) == 0:
        return []
    s_ego = plan.s[log["route_index"].astype(int)]
    h = stop_history(s_ego, log["v"], np.array([p.s_in for p in passages]))
    out = []
    for j, p in enumerate(passages):  # never left the zone: no verdict (the Leaderboard waits too)
        if h.reached[-1, j] and h.left[-1, j] and not h.stopped[-1, j]:
            x, y, _ = plan.path.pose(p.s_in)
            out.append(f"Agent ran a stop with id={p.junction} at {loc(x, y)}")
    return out


def outside_lanes(log: dict, plan: GlobalPlan, lanes: LaneIndex, spans, values: dict | None = None) -> list[str]:
    """The outside-lanes message; ``values`` (if given) gets the unrounded percentage under
    "outside_route_lanes" (the leaderboard's event value, which its penalty uses)."""
    xy = np.stack([log["x"], log["y"]], 1)
    if len(xy) == 0:
        return []
    near = lanes.nearest(xy)
    outside = near.dist > near.width / 2 + OUTSIDE_MARGIN
    diff = np.degrees((near.heading - log["yaw"]) % (2 * math.pi))
    wrong = (~near.junction) & (diff >= WRONG_DEG) & (diff <= 360.0 - WRONG_DEG)
    s_ego = plan.s[log["route_index"].astype(int)]
    for kind, s0, s1, params in spans:  # TwoWays scenarios switch the wrong-lane check off
        if two_ways(kind, params):
            wrong &= ~((s_ego >= s0) & (s_ego <= s1 + SCENARIO_END))
    fwd = np.stack([np.cos(plan.yaw), np.sin(plan.yaw)], 1)
    i, total, bad = 0, 0.0, 0.0
    n = len(plan.s)
    for k in range(len(xy)):
        for j in range(i + 1, min(i + 4, n)):
            if (xy[k] - plan.xy[j]) @ fwd[j] > 0:
                d = float(plan.s[j] - plan.s[i])
                total += d
                if outside[k] or wrong[k]:
                    bad += d
                i = j
    if bad <= 0:
        return []
    percentage = bad / total * 100  # in the leaderboard's order of operations
    if values is not None:
        values["outside_route_lanes"] = percentage
    return [f"Agent went outside its route lanes for about {round(bad, 3)} meters "
            f"({round(percentage, 2)}% of the completed route)"]


def min_speed(log: dict, plan: GlobalPlan, rules: str, ended_normally: bool) -> list[str]:
    checkpoints = MIN_SPEED_CHECKPOINTS[rules]
    cp = plan.length / checkpoints
    out, last_cp, sum_ego, sum_bg, n = [], 0.0, 0.0, 0.0, 0
    always = rules == "b2d"

    def close():
        value = round(100 * sum_ego / sum_bg, 2) if n > 0 and sum_bg != 0 else 100
        if always or value < 100:
            out.append(f"Average speed is {value}% of the surrounding traffic's one")

    cum = plan.s
    i = 0
    for k in range(len(log["t"])):
        i = int(log["route_index"][k])
        if cum[i] - last_cp > cp:
            close()
            last_cp, sum_ego, sum_bg, n = float(cum[i]), 0.0, 0.0, 0
        bg = log["bg_speed"][k]
        if not math.isnan(bg):
            sum_bg += bg
            sum_ego += log["v"][k]
            n += 1
    for _ in range(2 if ended_normally else 1):  # terminate() runs twice on a normal end
        if cum[i] / plan.length > 0.95:
            close()
    return out


def scenario_timeouts(log: dict, plan: GlobalPlan, spans) -> list[str]:
    out = []
    s_ego = plan.s[log["route_index"].astype(int)]
    t = log["t"]
    for kind, s0, s1, _ in spans:
        if not HAZARDS[kind].timeout:
            continue
        started = np.flatnonzero(s_ego >= s0)
        if len(started) == 0:
            continue
        t0 = t[started[0]]
        ended = np.flatnonzero(s_ego >= s1 + SCENARIO_END)
        t_end = t[ended[0]] if len(ended) else t[-1]
        if t_end - t0 > SCENARIO_TIMEOUT:
            out.append("Agent timed out a scenario")
    return out


def detect(log: dict, plan: GlobalPlan, route: Route, net, status: str, rules: str = "lb2.0",
           values: dict | None = None) -> dict[str, list[str]]:
    """All infraction lists of one route run, from its log and how it ended; ``values`` (if
    given) gets the unrounded value behind a percentage message (outside_lanes)."""
    ev = {k: [] for k in KEYS}
    if len(log["t"]) == 0:
        return ev
    spans = hazard_spans(plan, route)
    ev.update(collisions(log, spans))
    ev["red_light"] = red_lights(log, plan, net)
    ev["stop_infraction"] = stop_signs(log, plan)
    ev["outside_route_lanes"] = outside_lanes(log, plan, LaneIndex.for_town(route.town), spans, values)
    ev["min_speed_infractions"] = min_speed(log, plan, rules, ended_by_criterion(status))
    ev["scenario_timeouts"] = scenario_timeouts(log, plan, spans)
    ending = STATUSES.get(status)
    if ending is not None and ending.infraction:  # the criterion that ended the route, at the ego's last position
        ev[ending.infraction] = [ending.infraction_message.format(at=loc(log["x"][-1], log["y"][-1]))]
    return ev
