"""The towns: seeded builders (plain XML -> netconvert) and the built SUMO nets.

``net_path("town12")`` is the committed net; ``load_net`` reads it with sumolib
(internal lanes included) once per process; ``build`` rebuilds it from its builder.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import sumolib

from sumo_nets.plain import build_net
from sumo_nets.towns import DEFAULT_SEEDS, TOWNS

NETS_DIR = Path(__file__).resolve().parent / "nets"


class UnknownTown(ValueError):
    """A town name that has no builder."""


def check_town(town: str) -> str:
    """Return town if it is known, else raise UnknownTown naming the known ones."""
    if town not in TOWNS:
        raise UnknownTown(f"unknown town {town!r} (known: {', '.join(TOWNS)})")
    return town


def net_path(town: str) -> Path:
    """Path of the built ``<town>.net.xml``."""
    return NETS_DIR / f"{check_town(town)}.net.xml"


@lru_cache(maxsize=None)
def load_net(town: str) -> sumolib.net.Net:
    """The town's net as a sumolib object, with internal (junction) lanes; cached."""
    return sumolib.net.readNet(str(net_path(town)), withInternal=True)


def build(town: str, seed: int | None = None, out_dir: Path = NETS_DIR) -> Path:
    """Rebuild one town from its seeded builder; same seed -> byte-identical file."""
    seed = DEFAULT_SEEDS[check_town(town)] if seed is None else seed
    plain = TOWNS[town](np.random.default_rng(seed))
    note = f"{town} (seed {seed}), built by: sumo-scimm nets build"  # no '--' inside XML comments
    return build_net(plain, Path(out_dir) / f"{town}.net.xml", note)


__all__ = ["NETS_DIR", "TOWNS", "DEFAULT_SEEDS", "UnknownTown", "check_town", "net_path",
           "load_net", "build"]
