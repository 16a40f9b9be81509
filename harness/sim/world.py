"""The SUMO side of an episode: one libsumo simulation, the ego mirrored into it, and a
snapshot of every actor near the ego after each step.

libsumo holds one simulation per process (docs/design.md §3), so a World is
started and closed once per route inside a worker process.

The ego is a real SUMO vehicle (traffic sees and yields to it) placed every step with
``moveToXY(keepRoute=2)`` at the pose the harness integrated, plus ``setSpeed``; speed
mode 0 and lane-change mode 0, so SUMO never moves it by itself (docs/design.md §3).

Conventions: SUMO reports a vehicle's *front bumper* position and a heading in degrees
clockwise from north; the snapshot converts to centre position and yaw [rad, CCW from
+x], world frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import libsumo
import numpy as np

from controller.vehicle import DT, LENGTH, WIDTH, EgoState
from sumo_nets import net_path

EGO = "ego"
CONTEXT_RADIUS = 50.0  # actors within this distance of the ego are read each step [m]
PERSON_SIZE = 0.6  # box side of a pedestrian for drawing and contacts [m]
TLS_CODES = "rRyYgGsuoO"  # SUMO link states; light states are their index here, -1 if unknown
PERSON_PREFIX = "ped"  # every person the harness adds has an id starting with this

# actor classes, as the Leaderboard classifies the other party of a collision
VEHICLE, PEDESTRIAN, STATIC = 0, 1, 2

_POS, _ANGLE, _SPEED = libsumo.constants.VAR_POSITION, libsumo.constants.VAR_ANGLE, libsumo.constants.VAR_SPEED
_ROAD = libsumo.constants.VAR_ROAD_ID


def yaw_from_sumo(angle_deg: float) -> float:
    """SUMO heading (deg clockwise from north) -> yaw (rad CCW from +x)."""
    return math.radians(90.0 - angle_deg)


def sumo_angle(yaw: float) -> float:
    """Yaw (rad CCW from +x) -> SUMO heading (deg clockwise from north), in [0, 360)."""
    return (90.0 - math.degrees(yaw)) % 360.0


@dataclass
class Snapshot:
    """Actors near the ego after a step, world frame: centre x, y [m], yaw [rad],
    speed [m/s], length, width [m], class (VEHICLE / PEDESTRIAN / STATIC), id."""

    ids: list[str]
    xy: np.ndarray  # (K, 2)
    yaw: np.ndarray  # (K,)
    speed: np.ndarray  # (K,)
    size: np.ndarray  # (K, 2) length, width
    cls: np.ndarray  # (K,) int
    background_speed: float  # mean speed of the background vehicles that count, nan if none


class World:
    """A running libsumo simulation of one town, with the ego in it."""

    def __init__(self, town: str, seed: int, background_roads: frozenset[str] = frozenset()):
        """Start SUMO on the town's net. ``background_roads``: the edges whose background
        vehicles make the minimum-speed reference (all within CONTEXT_RADIUS if empty)."""
        self.background_roads = background_roads
        libsumo.start(["sumo", "-n", str(net_path(town)), "--step-length", str(DT),
                       "--seed", str(seed), "--no-step-log", "true", "--no-warnings", "true",
                       "--collision.action", "none", "--time-to-teleport", "120",
                       "--pedestrian.model", "striping", "--begin", "0"])
        self.time = 0.0
        self._types: dict[str, tuple[float, float, int, bool, float]] = {}
        # walkers the harness moves with moveToXY stand in a waiting stage, for which SUMO
        # reports speed 0; their scripted walking speed [m/s] by id (set by the hazards)
        self.walking: dict[str, float] = {}
        vt = libsumo.vehicletype
        vt.copy("DEFAULT_VEHTYPE", "ego")
        vt.setLength("ego", LENGTH)
        vt.setWidth("ego", WIDTH)
        vt.copy("DEFAULT_VEHTYPE", "background")
        vt.setLength("background", 4.6)
        vt.setWidth("background", 1.9)
        # 70 % of the limit: the background speed PDM-Lite assumes (docs/design.md §2.3)
        vt.setSpeedFactor("background", 0.7)
        vt.setSpeedDeviation("background", 0.05)
        vt.copy("background", "hazard")
        vt.setSpeedFactor("hazard", 0.8)
        vt.setSpeedDeviation("hazard", 0.0)
        for name, (length, width) in {"obstacle_parked_car": (4.6, 1.9), "obstacle_accident": (5.0, 2.4),
                                      "obstacle_construction": (4.0, 2.6)}.items():
            vt.copy("DEFAULT_VEHTYPE", name)
            vt.setLength(name, length)
            vt.setWidth(name, width)

    def close(self) -> None:
        libsumo.close()

    # --- the ego ------------------------------------------------------------------------
    def add_ego(self, edges: tuple[str, ...], lane: int, pos: float) -> None:
        self._ego_edges = list(edges)
        self._readds = 0
        libsumo.route.add("ego_route", list(edges))
        self._insert_ego("ego_route", str(lane), f"{pos + LENGTH / 2:.2f}")

    def _insert_ego(self, route_id: str, lane: str, pos: str) -> None:
        libsumo.vehicle.add(EGO, route_id, typeID="ego", departLane=lane, departPos=pos, departSpeed="0")
        libsumo.vehicle.setSpeedMode(EGO, 0)
        libsumo.vehicle.setLaneChangeMode(EGO, 0)
        libsumo.vehicle.subscribeContext(EGO, libsumo.constants.CMD_GET_VEHICLE_VARIABLE, CONTEXT_RADIUS,
                                         [_POS, _ANGLE, _SPEED, _ROAD])
        libsumo.vehicle.subscribeContext(EGO, libsumo.constants.CMD_GET_PERSON_VARIABLE, CONTEXT_RADIUS,
                                         [_POS, _ANGLE, _SPEED, _ROAD])

    def move_ego(self, s: EgoState, edge: str = "", lane: int = -1) -> None:
        """Place the ego (centre pose s) for the next step; SUMO wants the front bumper.

        edge, lane: the route's edge and lane at the ego, as SUMO's placement hint, so that
        an ego near the centre line is not mapped onto the opposite lane (where oncoming
        SUMO traffic would stop in front of it for good)."""
        fx = s.x + math.cos(s.yaw) * LENGTH / 2
        fy = s.y + math.sin(s.yaw) * LENGTH / 2
        try:
            libsumo.vehicle.moveToXY(EGO, edge, lane, fx, fy, sumo_angle(s.yaw), keepRoute=2)
        except libsumo.TraCIException:
            # SUMO dropped the ego: it teleported it out of a jam, or the ego ran off the end
            # of the one-edge route SUMO gives a vehicle moved off its route. Put it back.
            self._readds += 1
            libsumo.route.add(f"ego_route{self._readds}", self._ego_edges)
            self._insert_ego(f"ego_route{self._readds}", "best", "0")
            libsumo.vehicle.moveToXY(EGO, "", -1, fx, fy, sumo_angle(s.yaw), keepRoute=2)
        libsumo.vehicle.setSpeed(EGO, s.v)

    def step(self) -> None:
        libsumo.simulationStep()
        self.time += DT

    # --- reading the world --------------------------------------------------------------
    def _kind(self, vid: str) -> tuple[float, float, int, bool, float]:
        """(length, width, class, is_background, centre offset behind the reported position)
        of an actor, cached per id."""
        k = self._types.get(vid)
        if k is None:
            if vid.startswith(PERSON_PREFIX):  # SUMO reports a person's centre
                k = (PERSON_SIZE, PERSON_SIZE, PEDESTRIAN, False, 0.0)
            else:  # and a vehicle's front bumper
                t = libsumo.vehicle.getTypeID(vid)
                cls = STATIC if t.startswith("obstacle") else VEHICLE
                length = libsumo.vehicle.getLength(vid)
                k = (length, libsumo.vehicle.getWidth(vid), cls, t == "background", length / 2)
            self._types[vid] = k
        return k

    def snapshot(self) -> Snapshot:
        """Actors within CONTEXT_RADIUS of the ego (the ego excluded)."""
        ids, rows, bg = [], [], []
        kinds, roads = self._types, self.background_roads
        # one table for both context subscriptions (vehicles and persons), keyed by id
        for vid, var in (libsumo.vehicle.getContextSubscriptionResults(EGO) or {}).items():
            if vid == EGO:
                continue
            length, width, cls, is_bg, off = kinds.get(vid) or self._kind(vid)
            (fx, fy), v = var[_POS], var[_SPEED]
            if cls == PEDESTRIAN:
                v = self.walking.get(vid, v)
            yaw = yaw_from_sumo(var[_ANGLE])
            ids.append(vid)
            rows.append((fx - math.cos(yaw) * off, fy - math.sin(yaw) * off, yaw, v, length, width, cls))
            if is_bg and (not roads or var[_ROAD] in roads):
                bg.append(v)
        a = np.array(rows, dtype=float).reshape(-1, 7)
        # np.mean's arithmetic (NumPy's pairwise sum, one division) without its per-call cost
        return Snapshot(ids, a[:, :2], a[:, 2], a[:, 3], a[:, 4:6], a[:, 6].astype(int),
                        float(np.add.reduce(np.array(bg))) / len(bg) if bg else math.nan)

    def light_states(self, passages) -> list[int]:
        """State of the route's link at each light passage, as an index into TLS_CODES."""
        out = []
        for p in passages:
            state = libsumo.trafficlight.getRedYellowGreenState(p.tls)
            c = state[p.link] if 0 <= p.link < len(state) else "o"
            out.append(TLS_CODES.index(c) if c in TLS_CODES else -1)
        return out
