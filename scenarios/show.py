"""``sumo-scimm routes show``: a table of a route set, lengths measured along the lanes."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

from scenarios.check import check_route
from scenarios.hazards import HAZARDS
from scenarios.routefile import read_routes


def show_set(path: Path) -> str:
    """One line per route (id, town, length along the lanes, hazards) and a summary."""
    _, routes = read_routes(path)
    lines = [f"{'id':>5} {'town':7} {'length [m]':>10}  hazards"]
    lengths, per_type = [], Counter()
    for r in routes:
        length = check_route(r).length
        lengths.append(length)
        per_type.update({h.type for h in r.hazards})
        lines.append(f"{r.id:>5} {r.town:7} {length:10.1f}  " + ", ".join(h.type for h in r.hazards))
    towns = Counter(r.town for r in routes)
    lines.append("")
    lines.append(f"{len(routes)} routes ({', '.join(f'{t} {n}' for t, n in sorted(towns.items()))}); "
                 f"length {min(lengths):.1f}-{max(lengths):.1f} m, total {sum(lengths) / 1000:.2f} km; "
                 f"{sum(1 for r in routes if r.hazards)} with >= 1 hazard")
    lines.append("routes per hazard type: " + ", ".join(f"{t} {per_type[t]}" for t in HAZARDS))
    return "\n".join(lines)
