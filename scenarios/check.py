"""Route validation (``sumo-scimm routes check FILE``, docs/design.md §2.2).

A route passes when its town is known, its edges are consecutive and connected for
cars, its start and end positions lie on their lanes, its length along the lanes is
inside the set's bounds (``min_length``/``max_length`` on ``<routes>``, if given), every
keypoint lies on the traced route in order, and every hazard has a known type, valid
parameters, a trigger point on the route and a site (junction, crossing, lane) that the
route really passes.
"""
from __future__ import annotations

import math
from pathlib import Path

from sumo_nets import UnknownTown, check_town, load_net
from scenarios.geometry import RouteError, RoutePath, trace
from scenarios.hazards import check_params
from scenarios.routefile import Route, RouteFileError, load_tree, parse_route, set_bounds, short

ON_ROUTE = 3.0  # a keypoint or trigger point is "on the route" within this distance [m]


def check_route(route: Route, bounds: tuple[float, float] = (0.0, math.inf)) -> RoutePath:
    """Trace and validate one route; raises RouteFileError(route.id, reason) on the first problem."""
    rid = route.id
    try:
        net = load_net(check_town(route.town))
    except UnknownTown as exc:
        raise RouteFileError(rid, str(exc)) from None
    try:
        path = trace(net, list(route.edges), route.depart_pos, route.arrival_pos)
    except RouteError as exc:
        raise RouteFileError(rid, f"disconnected or off-net route: {exc}") from None
    lo, hi = bounds
    if not lo <= path.length <= hi:
        raise RouteFileError(rid, f"length {short(path.length)} m is outside the set's bounds [{lo:g}, {hi:g}] m")
    s_prev = -1.0
    for k, (x, y, _) in enumerate(route.waypoints):
        s, d = path.project(x, y, max(s_prev, 0.0))
        if d > ON_ROUTE:
            raise RouteFileError(rid, f"waypoint {k} ({short(x)}, {short(y)}) is {short(d)} m off the route's "
                                      f"edges: waypoints and edges disagree")
        s_prev = s
    passed = {p.junction for p in path.passages}
    lanes = {g.lane_in for g in path.legs}
    for h in route.hazards:
        reason = check_params(h.type, h.params)
        if reason:
            raise RouteFileError(rid, f"hazard {h.name!r}: {reason}")
        s, d = path.project(h.trigger[0], h.trigger[1])
        if d > ON_ROUTE:
            raise RouteFileError(rid, f"hazard {h.name!r}: trigger point is {short(d)} m off the route")
        if s + float(h.params["distance"]) > path.length + 1.0:
            raise RouteFileError(rid, f"hazard {h.name!r}: site lies beyond the route end")
        if "junction" in h.params and h.params["junction"] not in passed:
            raise RouteFileError(rid, f"hazard {h.name!r}: the route does not pass junction "
                                      f"{h.params['junction']!r}")
        if "crossing" in h.params and h.params["crossing"].lstrip(":").rsplit("_c", 1)[0] not in passed:
            raise RouteFileError(rid, f"hazard {h.name!r}: the route does not pass crossing "
                                      f"{h.params['crossing']!r}")
        if "lane" in h.params and h.params["lane"] not in lanes:
            raise RouteFileError(rid, f"hazard {h.name!r}: the route does not drive lane {h.params['lane']!r}")
    return path


def check_file(path: Path) -> tuple[int, list[RouteFileError]]:
    """(number of routes, problems): one problem per bad route, or one for the whole file."""
    try:
        root = load_tree(path)
    except RouteFileError as exc:
        return 0, [exc]
    try:
        bounds = set_bounds(root, path)
    except RouteFileError as exc:
        return 0, [exc]
    elements = root.findall("route")
    if not elements:
        return 0, [RouteFileError(None, f"{path}: no <route> elements")]
    problems, seen = [], set()
    for el in elements:
        try:
            route = parse_route(el)
            if route.id in seen:
                raise RouteFileError(route.id, "duplicate route id")
            seen.add(route.id)
            check_route(route, bounds)
        except RouteFileError as exc:
            problems.append(exc)
    return len(elements), problems


def problem_line(path: Path, problem: RouteFileError) -> str:
    """``path: problem`` with the file named once: the problems of a whole file (load_tree,
    set_bounds) name it already, a route's do not."""
    text = str(problem)
    return text if text.startswith(f"{path}: ") else f"{path}: {text}"
