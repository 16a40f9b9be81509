"""One episode = one route in libsumo at 0.05 s steps (docs/design.md §3).

Each tick, as in the leaderboard: the agent decides on the state after the last step
(sensors built from one snapshot), the harness integrates the ego with the vehicle
model and mirrors it into SUMO, hazards advance, SUMO steps, the new snapshot is read,
contacts and route-ending criteria are evaluated, and everything goes into the log; the
stop-sign state the next tick's BEV draws from (harness.sim.stop_signs) follows the logged
route index and speed.

An exception in the agent, a Control with NaN/inf, or a ``run_step`` that takes longer
than the per-step deadline (``agent_timeout``, wall clock, default AGENT_TIMEOUT) ends the
route as "Failed - Agent crashed", as the Leaderboard's agent watchdog does; the log up to
that tick is kept. That includes what an agent raises that is not an Exception
(SystemExit, KeyboardInterrupt, GeneratorExit); only the user's own Ctrl-C or SIGTERM
(harness.common.stops) goes on to stop the run. An exception in ``destroy`` is kept at
the end of the route's message. Every agent call runs under ``agent_call`` (its deadline
published to a watching parent, harness.runs.workers, which kills a worker whose agent
call does not return).
"""
from __future__ import annotations

import copy
import time as wallclock
import traceback
from dataclasses import dataclass, field

import numpy as np

from controller.ego import DEFAULT_VEHICLE, make_ego
from controller.vehicle import DT, LENGTH, WIDTH, Control, EgoState
from harness.common.stops import is_stop, watch_stops
from harness.scoring import criteria
from harness.scoring.statuses import FAILED_AGENT, FAILED_SETUP, FAILED_SIMULATION
from harness.loop.agent import (Prediction, agent_call, agent_for, exception_text, forget_agent, split_output,
                                validate_sensors)
from harness.loop.deadline import AGENT_TIMEOUT, deadline_alarm, step_with_deadline
from harness.loop.scene_log import SceneLog
from harness.sim.contacts import overlaps
from harness.sim.hazards import make_hazard
from harness.sim.plan import GlobalPlan, build_plan, to_ego
from harness.sim.stop_signs import StopTracker
from harness.sim.traffic import BackgroundTraffic, RouteBubble
from harness.sim.world import STATIC, Snapshot, World
from scenarios.routefile import Route
from sumo_nets import load_net

_NAN_PATH, _NAN_WPS = np.full((20, 2), np.nan), np.full((10, 2), np.nan)  # logged when there is no prediction
_NAN_PATH.flags.writeable = _NAN_WPS.flags.writeable = False


@dataclass
class EpisodeLog:
    """Per-tick arrays of one episode (world frame, SI units) and its contact events."""

    columns: dict[str, list] = field(default_factory=lambda: {k: [] for k in (
        "t", "x", "y", "yaw", "v", "steer", "throttle", "brake", "route_index", "rc", "bg_speed")})
    tls: list[list[int]] = field(default_factory=list)  # per tick, state code of each route light
    contacts: list[tuple[int, str, int]] = field(default_factory=list)  # (tick, actor id, class)
    path: list[np.ndarray] = field(default_factory=list)  # predicted path per tick (20, 2) or nan
    speed_wps: list[np.ndarray] = field(default_factory=list)  # predicted speed wps (10, 2) or nan
    scene: SceneLog = field(default_factory=SceneLog)  # what the agent saw each tick (for replay)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {k: np.asarray(v, dtype=float) for k, v in self.columns.items()}
        n = len(self.columns["t"])  # 0 when the route ended before its first tick (setup failed)
        out["tls"] = np.asarray(self.tls, dtype=np.int8).reshape(n, -1) if n else np.zeros((0, 0), np.int8)
        out["contact_tick"] = np.array([c[0] for c in self.contacts], dtype=np.int32)
        out["contact_actor"] = np.array([c[1] for c in self.contacts], dtype=str)
        out["contact_class"] = np.array([c[2] for c in self.contacts], dtype=np.int8)
        out["pred_path"] = np.asarray(self.path, dtype=np.float32).reshape(-1, 20, 2)
        out["pred_speed_wps"] = np.asarray(self.speed_wps, dtype=np.float32).reshape(-1, 10, 2)
        out.update(self.scene.arrays())
        return out


@dataclass(frozen=True)
class Frame:
    """What ``on_frame`` sees after a tick (read-only: it must not change the simulation)."""

    tick: int
    ego: EgoState
    snap: Snapshot
    plan: GlobalPlan
    pred: Prediction | None
    lights: list[int]  # state of each route light (index into harness.sim.world.TLS_CODES)
    props: list  # harness-only static boxes (x, y, yaw, length, width)
    control: Control
    agent: object  # the agent instance (the collector reads the expert's own state)
    stops: tuple[bool, ...]  # whether each route stop sign is still drawn (harness.sim.stop_signs)


@dataclass
class EpisodeResult:
    status: str
    rc: float
    game_time: float
    wall_time: float
    steps: int
    message: str
    log: EpisodeLog
    length: float  # route length along the lanes [m]
    plan: GlobalPlan | None = None
    loop_time: float = 0.0  # wall time of the tick loop alone [s] (no start-up, no teardown)


def sensor_inputs(specs: list[dict], ego: EgoState, plan: GlobalPlan, progress: int, snap: Snapshot,
                  world_view, bev_fn) -> dict:
    """The agent's sensor data {id: value} for the tick that starts at ego state ``ego``
    and dense route index ``progress`` (``bev_fn()`` renders the BEV when one is asked for)."""
    data = {}
    for spec in specs:
        t = spec["type"]
        if t == "speed":
            data[spec["id"]] = ego.v
        elif t == "pose":
            data[spec["id"]] = (ego.x, ego.y, ego.yaw)
        elif t == "target_point":
            data[spec["id"]] = to_ego(plan.target_xy(progress), ego.x, ego.y, ego.yaw)
        elif t == "command":
            data[spec["id"]] = int(plan.command[progress])
        elif t == "bev":
            data[spec["id"]] = bev_fn()
        elif t == "world":
            data[spec["id"]] = world_view
    return data


def run_episode(route: Route, agent_name: str, agent_config: str | None, seed: int,
                on_frame=None, agent_timeout: float = AGENT_TIMEOUT, vehicle: str = DEFAULT_VEHICLE) -> EpisodeResult:
    """Drive one route with an agent; ``seed`` fixes traffic, hazards, noise and SUMO.
    ``agent_timeout``: the per-step deadline of ``run_step`` [s of wall time]; ``vehicle``: the ego model.

    ``on_frame(frame)`` is called with a :class:`Frame` after every tick (rendering,
    recording); it must not change the simulation. An error ends the route with its
    status (harness.scoring.statuses), the log up to that tick kept.
    """
    wall0 = wallclock.perf_counter()
    ss = np.random.SeedSequence(seed)
    rngs = tuple(np.random.default_rng(s) for s in ss.spawn(3))  # traffic, hazards, ego
    net = load_net(route.town)
    plan = build_plan(route, net)
    run = _Run()
    ego = make_ego(vehicle, EgoState(*plan.path.pose(0.0), 0.0), rngs[2])
    world = World(route.town, int(ss.generate_state(1)[0] % (2**31 - 1)), background_roads(route, net))
    status, message, rc = FAILED_SIMULATION, "", 0.0  # until the route ends
    try:
        status, message, rc = _drive(run, route, net, plan, world, (*rngs[:2], ego), agent_name, agent_config, on_frame,
                                     agent_timeout)
    except _AgentSetupError as exc:
        status, message, rc = FAILED_SETUP, str(exc), 0.0
    except Exception as exc:  # noqa: BLE001 - a simulator failure ends this route only
        status, message = FAILED_SIMULATION, f"{type(exc).__name__}: {exc}"
        rc = run.log.columns["rc"][-1] if run.log.columns["rc"] else 0.0
        message += "\n" + traceback.format_exc(limit=4)
    finally:
        if run.agent is not None:
            stops = watch_stops()
            try:
                with agent_call(agent_timeout):
                    run.agent.destroy()
            except BaseException as exc:  # noqa: BLE001 - destroy errors must not hide the route result
                if is_stop(exc, stops):
                    raise
                message = f"{message}; " if message else ""
                message += f"destroy() raised {type(exc).__name__}: {exception_text(exc)}"
                forget_agent(agent_name)
            if status in (FAILED_AGENT, FAILED_SETUP):  # an instance that failed is not driven again
                forget_agent(agent_name)
        world.close()
    return EpisodeResult(status, float(rc), round(run.tick * DT, 3), wallclock.perf_counter() - wall0,
                         run.tick, message, run.log, plan.length, plan, run.loop_time)


@dataclass
class _Run:
    """An episode in progress: what its result keeps when it ends in an error."""

    log: EpisodeLog = field(default_factory=EpisodeLog)
    agent: object = None  # the agent instance once loaded (destroyed at the end)
    tick: int = 0  # ticks driven
    loop_time: float = 0.0  # wall time of the tick loop [s], set when it ends


def _drive(run: _Run, route: Route, net, plan: GlobalPlan, world: World, rngs: tuple, agent_name: str,
           agent_config: str | None, on_frame, agent_timeout: float) -> tuple[str, str, float]:
    """Set up the scene and the agent, then tick until a criterion ends the route or the
    agent fails; returns (status, message, RC). ``rngs``: the traffic and hazard generators
    and the ego (controller.ego). A failing agent set-up raises _AgentSetupError; any other
    error (the simulator's, the harness's) propagates."""
    from harness.sensors.bev import BevRenderer  # the renderer pulls OpenCV; keep import local

    rng_traffic, rng_hazard, ego = rngs
    scene = Scene(route, net, plan, world, rng_traffic, rng_hazard)
    scene.start(ego.state)
    snap = world.snapshot()
    lights = [p for p in plan.passages if p.tls]
    bev = BevRenderer.for_town(route.town)
    specs = _setup_agent(run, agent_name, agent_config, plan, agent_timeout)
    ends = _RouteEnd(plan)
    signs = StopTracker(plan)  # which stop signs the BEV still draws
    props = scene.props
    prop_boxes = np.array(props, dtype=float).reshape(-1, 5)  # (P, 5) x, y, yaw, length, width
    end = None
    alarm, stops = deadline_alarm(), watch_stops()
    loop0 = wallclock.perf_counter()
    lights_now = world.light_states(lights)
    while end is None:
        s = ego.state
        progress, drawn = ends.done.progress.index, signs.drawn  # drawn: the stop lines still to obey
        try:
            inputs = sensor_inputs(specs, s, plan, progress, snap, (snap, lights_now, props),
                                   lambda: bev.render(s, snap, plan, lights_now, props, drawn))
            control, pred = _agent_step(run.agent, inputs, world.time, agent_timeout, alarm)
        except BaseException as exc:  # noqa: BLE001 - an agent failure ends this route only
            if is_stop(exc, stops):  # the user's Ctrl-C or SIGTERM, not the agent's
                raise
            run.loop_time = wallclock.perf_counter() - loop0
            return FAILED_AGENT, f"{type(exc).__name__}: {exception_text(exc)}", ends.done.rc
        run.log.scene.add(world.time, s, progress, snap, lights_now, prop_boxes, drawn)  # the scene the agent saw
        s = ego.step(control)
        ego_s = float(plan.s[progress])
        scene.advance(s, ego_s)
        snap = world.snapshot()
        lights_now = world.light_states(lights)  # the state the next tick sees
        run.tick += 1
        # Blocked reads ``paused`` only below its speed: the hazards are asked only then
        paused = s.v < criteria.Blocked.SPEED and any(h.timeout_active(ego_s, world.time) for h in scene.hazards)
        end = ends.update(s, world.time, paused)
        _log_tick(run.log, run.tick, world.time, s, control, pred, ends.done, snap, lights_now, prop_boxes)
        signs.update(plan.s[ends.done.progress.index], s.v)  # the logged route index and speed
        if on_frame is not None:
            on_frame(Frame(run.tick, s, snap, plan, pred, lights_now, props, control, run.agent, signs.drawn))
    run.loop_time = wallclock.perf_counter() - loop0
    return end, "", ends.done.rc


def _setup_agent(run: _Run, agent_name: str, agent_config: str | None, plan: GlobalPlan,
                 timeout: float) -> list[dict]:
    """This process's agent (built on its first route) into ``run``, given the plan and set
    up; returns its validated sensor specs. Each call runs under the deadline ``timeout``
    [s] (harness.loop.agent.agent_call). Any failure raises _AgentSetupError."""
    stops = watch_stops()
    try:
        with agent_call(timeout):
            run.agent = agent_for(agent_name)
        with agent_call(timeout):
            run.agent.set_global_plan(copy.deepcopy(plan))  # the agent's own: it cannot move the scored route
            run.agent.setup(agent_config)
        with agent_call(timeout):
            specs = run.agent.sensors()
        validate_sensors(specs)
    except BaseException as exc:  # noqa: BLE001 - any agent failure is recorded, the run goes on
        if is_stop(exc, stops):
            raise
        raise _AgentSetupError(f"{type(exc).__name__}: {exception_text(exc)}") from exc
    return specs


def _agent_step(agent, inputs: dict, timestamp: float, timeout: float,
                alarm: bool) -> tuple[Control, Prediction | None]:
    """The agent's control and prediction for one tick, under the step deadline, checked by
    split_output (a non-finite control raises ValueError)."""
    return split_output(step_with_deadline(agent, inputs, timestamp, timeout, alarm))


class _RouteEnd:
    """The route-ending criteria, asked in the Leaderboard's order: the first that answers
    ends the route, and the ones after it are not updated on that tick."""

    def __init__(self, plan: GlobalPlan):
        self.done = criteria.RouteCompletion(plan)  # also the route index and RC
        self.in_route, self.blocked = criteria.InRoute(plan), criteria.Blocked()
        self.timeout = criteria.RouteTimeout(plan)

    def update(self, s: EgoState, time: float, paused: bool) -> str | None:
        """The status that ends the route at ego state s and simulation time [s], or None;
        ``paused``: a scenario timeout runs (Blocked is off)."""
        return (self.done.update(s.x, s.y) or self.in_route.update(s.x, s.y)
                or self.blocked.update(s.v, time, paused=paused)
                or self.timeout.update(s.x, s.y, time))


class Scene:
    """Everything SUMO simulates in an episode: the ego mirrored into it, the route's
    hazards, the background traffic and the route bubble. ``advance`` is the simulation's
    half of a tick; ``sumo_scimm.bench.closed_loop`` replays a logged ego through it to time SUMO and
    its traffic alone."""

    def __init__(self, route: Route, net, plan: GlobalPlan, world: World,
                 rng_traffic: np.random.Generator, rng_hazard: np.random.Generator):
        self.world = world
        world.add_ego(route.edges, net.getLane(plan.path.legs[0].lane_in).getIndex(), route.depart_pos)
        self.hazards = [make_hazard(h, plan, net, rng_hazard, k) for k, h in enumerate(route.hazards)]
        for h in self.hazards:
            h.setup()
        self.traffic = BackgroundTraffic(net, plan, rng_traffic)
        self.traffic.populate()
        quiet = tuple(q for q in (h.quiet_span() for h in self.hazards) if q is not None)
        self.bubble = RouteBubble(net, plan, quiet)
        self.props = [p for h in self.hazards for p in h.props]  # harness-only static boxes
        self._legs = [(g.s1, g.edge, net.getLane(g.lane_in).getIndex()) for g in plan.path.legs]

    def start(self, s: EgoState) -> None:
        """The ego at its start pose s, and SUMO's first step."""
        self.world.move_ego(s)
        self.world.step()

    def _hint(self, s_route: float) -> tuple[str, int]:
        """The route's edge and lane at arc length s [m] (the junction after it counts as it)."""
        for s1, edge, lane in self._legs:
            if s_route <= s1:
                return edge, lane
        return self._legs[-1][1], self._legs[-1][2]

    def advance(self, s: EgoState, ego_s: float) -> None:
        """One tick: the ego placed at s (route arc length ego_s [m]), hazards and traffic
        updated, SUMO stepped."""
        world = self.world
        world.move_ego(s, *self._hint(ego_s))
        for h in self.hazards:
            h.update(ego_s, world.time, s.v)
        world.walking = {pid: v for h in self.hazards for pid, v in h.walking().items()}
        self.traffic.update()
        self.bubble.update(ego_s, (s.x, s.y), world.time)
        world.step()


def background_roads(route: Route, net) -> frozenset[str]:
    """Edges whose background vehicles are the minimum-speed reference: the route's edges
    and their reverse. The Leaderboard's reference is its background bubble: vehicles
    ahead of and behind the ego in its lanes and in the opposite lanes; cross traffic that
    has green while the ego waits at a red light is not what it compares with."""
    roads = set(route.edges)
    for e in route.edges:
        edge = net.getEdge(e)
        rev = f"{edge.getToNode().getID()}_{edge.getFromNode().getID()}"
        if net.hasEdge(rev):
            roads.add(rev)
    return frozenset(roads)


class _AgentSetupError(Exception):
    pass


def _log_tick(log: EpisodeLog, tick: int, t: float, s: EgoState, c: Control, pred: Prediction | None,
              done: criteria.RouteCompletion, snap: Snapshot, lights: list[int], props: np.ndarray) -> None:
    """Append one tick to the log; ``props``: (P, 5) harness-only static boxes."""
    col = log.columns
    col["t"].append(t)
    col["x"].append(s.x)
    col["y"].append(s.y)
    col["yaw"].append(s.yaw)
    col["v"].append(s.v)
    col["steer"].append(c.steer)
    col["throttle"].append(c.throttle)
    col["brake"].append(c.brake)
    col["route_index"].append(done.progress.index)
    col["rc"].append(done.rc)
    col["bg_speed"].append(snap.background_speed)
    log.tls.append(lights)
    ego_box = (s.x, s.y, s.yaw, LENGTH, WIDTH)
    hit = overlaps(ego_box, snap.xy, snap.yaw, snap.size)
    for k in np.flatnonzero(hit):
        log.contacts.append((tick, snap.ids[k], int(snap.cls[k])))
    if len(props):
        for k in np.flatnonzero(overlaps(ego_box, props[:, :2], props[:, 2], props[:, 3:5])):
            log.contacts.append((tick, f"prop{k}", STATIC))
    log.path.append(pred.path if pred is not None and pred.path is not None else _NAN_PATH)
    log.speed_wps.append(pred.speed_wps if pred is not None and pred.speed_wps is not None else _NAN_WPS)
