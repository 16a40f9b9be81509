"""Route sets: Leaderboard-2.0-style route XML with SUMO edge lists and hazards (docs/design.md §2.2).

A set is named by its file stem: ``resolve_set("town12_short")`` is
``scenarios/town12_short.xml``; a path to any route file works too.
"""
from __future__ import annotations

from pathlib import Path

from scenarios.make import SETS, set_path


class UnknownSet(ValueError):
    """A route set name that is neither a shipped set nor an existing file."""


def resolve_set(name: str) -> Path:
    """Path of route set ``name`` (a shipped set's name or a path to a route file)."""
    p = set_path(name)
    if p.is_file():
        return p
    q = Path(name)
    if q.suffix == ".xml" or q.is_file() or "/" in name:
        if q.is_file():
            return q
        raise UnknownSet(f"route file {name!r} does not exist")
    shipped = sorted(x.stem for x in set_path("x").parent.glob("*.xml"))
    raise UnknownSet(f"unknown route set {name!r} (shipped: {', '.join(shipped) or 'none'}; "
                     f"or give the path of a route file)")


__all__ = ["SETS", "UnknownSet", "resolve_set", "set_path"]
