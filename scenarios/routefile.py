"""Route files: CARLA Leaderboard 2.0 route XML plus the SUMO edge list of each route.

Layout (one file = one route set; the Leaderboard's parser reads it, ignoring ``<sumo>``)::

    <routes set="town12_short" seed="1200" min_length="270" max_length="330">
      <route id="0" town="town12">
        <waypoints>
          <position x="905.1" y="1010.3" z="0.0"/>  ...   (world frame, m)
        </waypoints>
        <scenarios>
          <scenario name="ParkedObstacle_1" type="ParkedObstacle">
            <trigger_point x="..." y="..." z="0.0" yaw="90.0"/>  (yaw: deg, CCW from +x)
            <distance value="40.0"/> <variant value="accident"/> ...
          </scenario>
        </scenarios>
        <sumo edges="d11_d12 d12_d02" depart_pos="10.00" arrival_pos="50.00" length="301.20"/>
      </route>
    </routes>

The ``min_length``/``max_length`` attributes are the set's length bounds [m] (checked by
``routes check``); ``length`` is the route length along the lanes, for reference.
XML is parsed with defusedxml: DTDs and entities are refused (no entity expansion).

Every number is checked as it is read: finite, and in its range (coordinates within
COORD_LIMIT of the origin, positions along lanes and lengths >= 0 and > 0, yaw within
+-360 deg); a problem is a RouteFileError naming the element, the attribute and the
range, with over-long values cut (``clip_numbers``).

A route id names the route's files in a run folder (``logs/<id>_rep<k>.npz``, its dataset
episode): it must be a safe file name, 1 to 64 letters, digits, ``_``, ``-`` or ``.``,
starting with a letter or digit (``ROUTE_ID``); ``../x``, ``/tmp/x`` or ``a/b`` is a
RouteFileError before anything runs. The set's ``seed`` attribute, if given, is an
integer >= 0.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree.ElementTree import Element, ParseError, SubElement, indent, tostring

import defusedxml.ElementTree as SafeET
from defusedxml import DefusedXmlException

from files.atomic import write_atomic


COORD_LIMIT = 1e7  # |x|, |y|, |z| and positions along a lane [m]: 10,000 km, beyond any net
YAW_LIMIT = 360.0  # |yaw| of a trigger point [deg]
_LONG_NUMBER = re.compile(r"\d{20,}")
_VALUE_WIDTH = 16  # characters of an attribute value quoted in a message
ROUTE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")  # a route id: a safe file name


def id_problem(rid: str) -> str | None:
    """Why ``rid`` cannot be a route id (it names files in a run folder), or None."""
    if ROUTE_ID.fullmatch(rid):
        return None
    shown = rid if len(rid) <= 40 else f"{rid[:40]}... ({len(rid)} characters)"
    return (f"route id {shown!r} is not a safe file name: use 1 to 64 letters, digits, '_', '-' or '.', "
            "starting with a letter or digit")


def clip_numbers(text: str) -> str:
    """``text`` with every run of 20 or more digits cut to its first 8 (a message stays one
    readable line whatever number a file or an option held)."""
    return _LONG_NUMBER.sub(lambda m: f"{m[0][:8]}...({len(m[0])} digits)", text)


def short(v: float) -> str:
    """A number of metres for a message: one decimal, or 3 significant digits when huge."""
    return f"{v:.1f}" if abs(v) < 1e9 else f"{v:.3g}"


class RouteFileError(ValueError):
    """A problem with a route file; ``route_id`` is None for file-level problems."""

    def __init__(self, route_id: str | None, reason: str):
        reason = clip_numbers(reason)
        self.route_id = None if route_id is None else clip_numbers(
            route_id if len(route_id) <= 40 else f"{route_id[:40]}...")
        self.reason = reason
        super().__init__(f"route {self.route_id}: {reason}" if route_id is not None else reason)


@dataclass(frozen=True)
class Hazard:
    """One Leaderboard-style scenario of a route (see scenarios.hazards for types)."""

    name: str
    type: str
    trigger: tuple[float, float, float, float]  # world x, y, z [m] and yaw [deg, CCW from +x]
    params: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Route:
    """One route: Leaderboard keypoints, hazards and the SUMO edges it drives."""

    id: str
    town: str
    waypoints: tuple[tuple[float, float, float], ...]  # world frame [m]
    hazards: tuple[Hazard, ...]
    edges: tuple[str, ...]
    depart_pos: float  # [m] along the first edge's lane
    arrival_pos: float  # [m] along the last edge's lane
    length: float = math.nan  # [m] along the lanes, as written by the builder


def number(raw: str, what: str, lo: float, hi: float, open_lo: bool = False) -> float:
    """``raw`` as a finite number in [lo, hi] (``open_lo``: in (lo, hi]); otherwise
    ValueError whose text names ``what`` (e.g. "<sumo> length"), the value and the range."""
    shown = raw if len(raw) <= _VALUE_WIDTH else f"{raw[:_VALUE_WIDTH]}... ({len(raw)} characters)"
    try:
        v = float(raw)
    except ValueError:
        raise ValueError(f"{what}={shown!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{what}={shown!r} is not finite")
    if not (lo < v if open_lo else lo <= v) or v > hi:
        raise ValueError(f"{what}={shown!r} is outside {'(' if open_lo else '['}{lo:g}, {hi:g}]")
    return v


def _num(el: Element, key: str, rid: str | None, lo: float = -COORD_LIMIT, hi: float = COORD_LIMIT,
         default: float | None = None, open_lo: bool = False) -> float:
    """Attribute ``key`` of ``el`` as a number in [lo, hi] (``default`` if absent, when given)."""
    raw = el.get(key)
    if raw is None:
        if default is not None:
            return default
        raise RouteFileError(rid, f"<{el.tag}> has no {key!r} attribute")
    try:
        return number(raw, f"<{el.tag}> {key}", lo, hi, open_lo)
    except ValueError as exc:
        raise RouteFileError(rid, str(exc)) from None


def parse_route(el: Element) -> Route:
    """One ``<route>`` element -> Route; raises RouteFileError naming the route."""
    rid = el.get("id")
    if rid is None or not rid.strip():
        raise RouteFileError(None, "a <route> has no id")
    bad = id_problem(rid)
    if bad:
        raise RouteFileError(None, bad)
    town = el.get("town")
    if not town:
        raise RouteFileError(rid, "no town attribute")
    wps = el.find("waypoints")
    if wps is None or len(wps.findall("position")) < 2:
        raise RouteFileError(rid, "needs <waypoints> with at least two <position>")
    waypoints = tuple((_num(p, "x", rid), _num(p, "y", rid), _num(p, "z", rid) if p.get("z") else 0.0)
                      for p in wps.findall("position"))  # an empty z counts as 0, as before
    hazards = []
    for sc in (el.find("scenarios") if el.find("scenarios") is not None else []):
        if sc.tag != "scenario":
            continue
        tp = sc.find("trigger_point")
        if tp is None:
            raise RouteFileError(rid, f"scenario {sc.get('name')!r} has no <trigger_point>")
        trig = (_num(tp, "x", rid), _num(tp, "y", rid), _num(tp, "z", rid, default=0.0),
                _num(tp, "yaw", rid, -YAW_LIMIT, YAW_LIMIT))
        params = {}
        for child in sc:
            if child.tag == "trigger_point":
                continue
            if child.get("value") is None:
                raise RouteFileError(rid, f"scenario {sc.get('name')!r}: <{child.tag}> has no value")
            params[child.tag] = child.get("value")
        hazards.append(Hazard(sc.get("name", ""), sc.get("type", ""), trig, params))
    sumo = el.find("sumo")
    if sumo is None or not (sumo.get("edges") or "").split():
        raise RouteFileError(rid, "no <sumo edges=...> edge list")
    length = _num(sumo, "length", rid, 0.0, COORD_LIMIT, open_lo=True) if sumo.get("length") else math.nan
    return Route(rid, town, waypoints, tuple(hazards), tuple(sumo.get("edges").split()),
                 _num(sumo, "depart_pos", rid, 0.0), _num(sumo, "arrival_pos", rid, 0.0), length)


def set_bounds(root: Element, path: Path) -> tuple[float, float]:
    """The set's length bounds [m] (``min_length``, ``max_length`` on ``<routes>``; absent:
    0 and infinity); RouteFileError unless finite, >= 0 and min <= max."""
    try:
        lo = number(root.get("min_length"), "min_length", 0.0, COORD_LIMIT) if root.get("min_length") else 0.0
        hi = number(root.get("max_length"), "max_length", 0.0, COORD_LIMIT) if root.get("max_length") else math.inf
    except ValueError as exc:
        raise RouteFileError(None, f"{path}: <routes> {exc}") from None
    if lo > hi:
        raise RouteFileError(None, f"{path}: <routes> min_length {lo:g} is above max_length {hi:g}")
    seed = root.get("seed")
    if seed is not None and not re.fullmatch(r"[0-9]{1,20}", seed.strip()):
        raise RouteFileError(None, f"{path}: <routes> seed={seed[:_VALUE_WIDTH]!r} is not an integer >= 0")
    return lo, hi


def load_tree(path: Path) -> Element:
    """Parse a route file safely; raises RouteFileError for unreadable or non-route XML."""
    path = Path(path)
    if not path.is_file():
        raise RouteFileError(None, f"{path}: no such route file")
    try:
        root = SafeET.parse(str(path)).getroot()
    except DefusedXmlException as exc:
        raise RouteFileError(None, f"{path}: refused ({type(exc).__name__}: DTDs and entities are not allowed)") from None
    except ParseError as exc:
        raise RouteFileError(None, f"{path}: malformed XML ({exc})") from None
    except (LookupError, ValueError) as exc:  # an XML declaration naming an encoding Python cannot decode
        # with (UnicodeError is a ValueError); route files are UTF-8
        raise RouteFileError(None, f"{path}: cannot decode it ({type(exc).__name__}: {exc}): save it as UTF-8") from None
    if root.tag != "routes":
        raise RouteFileError(None, f"{path}: root element is <{root.tag}>, expected <routes>")
    return root


def read_routes(path: Path) -> tuple[dict[str, str], list[Route]]:
    """(set attributes, routes) of a route file; raises RouteFileError on the first problem."""
    root = load_tree(path)
    set_bounds(root, path)
    routes = [parse_route(el) for el in root.findall("route")]
    if not routes:
        raise RouteFileError(None, f"{path}: no <route> elements")
    return dict(root.attrib), routes


def _fmt(v: float) -> str:
    return f"{v:.2f}"


def write_routes(path: Path, meta: dict[str, str], routes: list[Route]) -> Path:
    """Write routes in the layout above, whole or not at all (files.atomic)."""
    root = Element("routes", meta)
    for r in routes:
        el = SubElement(root, "route", {"id": r.id, "town": r.town})
        wps = SubElement(el, "waypoints")
        for x, y, z in r.waypoints:
            SubElement(wps, "position", {"x": _fmt(x), "y": _fmt(y), "z": _fmt(z)})
        scs = SubElement(el, "scenarios")
        for h in r.hazards:
            sc = SubElement(scs, "scenario", {"name": h.name, "type": h.type})
            x, y, z, yaw = h.trigger
            SubElement(sc, "trigger_point", {"x": _fmt(x), "y": _fmt(y), "z": _fmt(z), "yaw": _fmt(yaw)})
            for k, v in h.params.items():
                SubElement(sc, k, {"value": v})
        SubElement(el, "sumo", {"edges": " ".join(r.edges), "depart_pos": _fmt(r.depart_pos),
                                "arrival_pos": _fmt(r.arrival_pos), "length": _fmt(r.length)})
    indent(root, "  ")
    path = Path(path)
    write_atomic(path, b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8") + b"\n")
    return path
