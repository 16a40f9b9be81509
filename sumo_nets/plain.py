"""Plain-XML road networks and the netconvert call that turns them into SUMO nets.

A town builder describes its roads as nodes (junctions, with a SUMO junction type) and
two-way roads between them (a road class and an optional curved centre line). This
module writes that description as SUMO plain XML (``*.nod.xml``, ``*.edg.xml``) and runs
``netconvert`` from the ``eclipse-sumo`` wheel with one fixed set of options, so that
the same description always gives the same ``*.net.xml`` byte for byte.

Frames and units: SUMO world frame (x east, y north), metres, m/s.
"""
from __future__ import annotations

import math
import re
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from files.atomic import write_atomic

KMH = 1.0 / 3.6  # km/h -> m/s

Point = tuple[float, float]


@dataclass(frozen=True)
class RoadClass:
    """How one kind of road is built (both directions get the same)."""

    name: str
    speed: float  # speed limit [m/s]
    lanes: int  # driving lanes per direction
    lane_width: float  # [m]; docs/design.md §2.1 wants 3-3.5 m
    priority: int  # SUMO edge priority: higher roads get right of way at priority junctions
    sidewalk: float  # sidewalk width [m] on the right of each direction


# Road classes by docs/design.md §2.1: speed limits 30 / 50 / 60 km/h, lanes 3-3.5 m wide.
RESIDENTIAL = RoadClass("residential", 30 * KMH, 1, 3.0, 1, 2.0)
TOWN = RoadClass("town", 50 * KMH, 1, 3.25, 2, 2.0)
DOWNTOWN = RoadClass("downtown", 50 * KMH, 2, 3.5, 3, 3.0)
RURAL = RoadClass("rural", 60 * KMH, 1, 3.25, 2, 1.5)
ARTERIAL = RoadClass("arterial", 60 * KMH, 2, 3.5, 4, 2.5)

# SUMO junction types a builder may ask for.
NODE_TYPES = ("priority", "traffic_light", "priority_stop", "allway_stop", "right_before_left")


@dataclass
class PlainNet:
    """A town as nodes and two-way roads, before netconvert.

    Edge ids are ``"{from}_{to}"``; a road between a and b gives edges ``a_b`` and ``b_a``
    with mirrored centre lines, so lanes of both directions sit side by side.
    """

    name: str
    nodes: dict[str, tuple[float, float, str]] = field(default_factory=dict)
    roads: list[tuple[str, str, RoadClass, tuple[Point, ...]]] = field(default_factory=list)

    def node(self, nid: str, x: float, y: float, kind: str = "priority") -> str:
        """Add a junction at world (x, y) [m]; ``kind`` is a SUMO junction type."""
        if kind not in NODE_TYPES:
            raise ValueError(f"node {nid}: unknown junction type {kind!r}")
        if nid in self.nodes:
            raise ValueError(f"node {nid} defined twice")
        self.nodes[nid] = (round(float(x), 2), round(float(y), 2), kind)
        return nid

    def set_kind(self, nid: str, kind: str) -> None:
        """Change the junction type of an existing node."""
        if kind not in NODE_TYPES:
            raise ValueError(f"node {nid}: unknown junction type {kind!r}")
        x, y, _ = self.nodes[nid]
        self.nodes[nid] = (x, y, kind)

    def xy(self, nid: str) -> Point:
        x, y, _ = self.nodes[nid]
        return (x, y)

    def road(self, a: str, b: str, cls: RoadClass, bend: float = 0.0,
             wiggle: float = 0.0, shape: tuple[Point, ...] = ()) -> None:
        """Add a two-way road from node a to node b.

        bend: sagitta [m] of a circular arc through both ends (positive bulges left of a->b).
        wiggle: amplitude [m] of one full sine period across the chord (an S-bend).
        shape: explicit interior points instead (world frame); overrides bend and wiggle.
        """
        if a not in self.nodes or b not in self.nodes:
            raise ValueError(f"road {a}-{b}: unknown node")
        if not shape:
            shape = curve(self.xy(a), self.xy(b), bend, wiggle)
        self.roads.append((a, b, cls, tuple((round(x, 2), round(y, 2)) for x, y in shape)))

    def degree(self, nid: str) -> int:
        return sum(nid in (a, b) for a, b, _, _ in self.roads)

    def write(self, folder: Path) -> tuple[Path, Path]:
        """Write ``<name>.nod.xml`` and ``<name>.edg.xml`` into folder; return both paths."""
        nod = folder / f"{self.name}.nod.xml"
        edg = folder / f"{self.name}.edg.xml"
        lines = ["<nodes>"]
        for nid, (x, y, kind) in self.nodes.items():
            lines.append(f'    <node id="{nid}" x="{x:.2f}" y="{y:.2f}" type="{kind}"/>')
        lines.append("</nodes>")
        nod.write_text("\n".join(lines) + "\n")
        lines = ["<edges>"]
        for a, b, cls, pts in self.roads:
            for u, v, inner in ((a, b, pts), (b, a, tuple(reversed(pts)))):
                attrs = (f'id="{u}_{v}" from="{u}" to="{v}" type={quoteattr(cls.name)} '
                         f'numLanes="{cls.lanes}" speed="{cls.speed:.3f}" '
                         f'width="{cls.lane_width:.2f}" priority="{cls.priority}" '
                         f'sidewalkWidth="{cls.sidewalk:.2f}"')
                if inner:
                    attrs += ' shape="' + " ".join(f"{x:.2f},{y:.2f}" for x, y in
                                                   ((self.xy(u),) + inner + (self.xy(v),))) + '"'
                lines.append(f"    <edge {attrs}/>")
        lines.append("</edges>")
        edg.write_text("\n".join(lines) + "\n")
        return nod, edg


def curve(p0: Point, p1: Point, bend: float = 0.0, wiggle: float = 0.0,
          step: float = 8.0) -> tuple[Point, ...]:
    """Interior points of a curved centre line from p0 to p1 (ends excluded).

    The offset from the chord at fraction t is a circular arc of sagitta ``bend`` plus
    ``wiggle * sin(2 pi t)``; points every ``step`` metres of chord. Positive offsets lie
    to the left of p0->p1.
    """
    if bend == 0.0 and wiggle == 0.0:
        return ()
    (x0, y0), (x1, y1) = p0, p1
    chord = math.hypot(x1 - x0, y1 - y0)
    n = max(4, int(chord / step))
    t = np.arange(1, n) / n
    nx, ny = -(y1 - y0) / chord, (x1 - x0) / chord  # left normal
    off = np.zeros_like(t)
    if bend:
        # exact circular arc: radius from chord and sagitta, offset along the chord
        r = (chord ** 2 / 4 + bend ** 2) / (2 * abs(bend))
        u = (t - 0.5) * chord
        off += math.copysign(1.0, bend) * (np.sqrt(r ** 2 - u ** 2) - (r - abs(bend)))
    if wiggle:
        off += wiggle * np.sin(2 * math.pi * t)
    return tuple((float(x0 + (x1 - x0) * ti + nx * oi), float(y0 + (y1 - y0) * ti + ny * oi))
                 for ti, oi in zip(t, off))


# netconvert options shared by every town. Sidewalks come from each edge's sidewalkWidth;
# crossings are guessed at every junction whose roads are below 61 km/h (all of ours);
# junction and TLS types come from the nodes, never guessed.
NETCONVERT_OPTIONS = (
    "--crossings.guess", "true",
    "--crossings.guess.speed-threshold", "17",
    "--walkingareas", "true",
    "--no-turnarounds", "true",
    "--tls.guess", "false",
    "--tls.default-type", "static",
    "--tls.cycle.time", "60",
    "--junctions.join", "false",
    "--junctions.corner-detail", "5",
    "--offset.disable-normalization", "true",
    "--geometry.remove", "false",
    "--no-warnings", "true",
    "--seed", "0",
)

# netconvert's header comment holds the build time and the temporary input paths.
_HEADER = re.compile(rb"<!-- generated on .*?\n-->\n", re.DOTALL)


def netconvert_binary() -> str:
    """Path of netconvert from the eclipse-sumo wheel (falls back to PATH)."""
    try:
        import sumo  # the eclipse-sumo wheel
        exe = Path(sumo.SUMO_HOME) / "bin" / "netconvert"
        if exe.exists():
            return str(exe)
    except ImportError:
        pass
    return "netconvert"


def build_net(plain: PlainNet, out: Path, note: str = "") -> Path:
    """Run netconvert on ``plain`` and write ``out`` (a ``*.net.xml``), reproducibly.

    netconvert's header comment (build time, temporary paths) is replaced by ``note``, so
    that rebuilding gives a byte-identical file.
    """
    out = Path(out)
    with tempfile.TemporaryDirectory() as tmp:
        nod, edg = plain.write(Path(tmp))
        raw = Path(tmp) / "net.xml"
        cmd = [netconvert_binary(), "--node-files", str(nod), "--edge-files", str(edg),
               "--output-file", str(raw), *NETCONVERT_OPTIONS]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"netconvert failed for {plain.name}: {res.stderr.strip()[-2000:]}")
        data, n = _HEADER.subn(f"<!-- {note} -->\n".encode(), raw.read_bytes(), count=1)
        if n != 1:
            raise RuntimeError("netconvert output has no header comment to replace")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, data)
    return out
