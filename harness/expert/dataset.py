"""Reading what ``sumo-scimm collect`` wrote: the frame index, episodes, and the BEV of a
stored frame rendered with the closed-loop renderer (so training sees exactly what the
agent sees in closed loop), with optional shift/rotation augmentation.

Augmentation moves the ego's viewpoint by ``shift`` metres to its left and turns it by
``rot`` radians (counter-clockwise); the BEV is rendered at that pose and every label
(path, speed waypoints, target point) is expressed in the moved ego frame:
p' = R(-rot) (p - (0, shift)).
"""
from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from controller.vehicle import EgoState
from files.atomic import write_atomic
from harness.common.errors import BadInput
from harness.common.npz import check_offsets, check_rows, read_npz
from harness.sensors.bev import BevRenderer
from harness.sim.plan import GlobalPlan, build_plan
from harness.sim.world import Snapshot
from scenarios import set_path
from scenarios.routefile import read_routes
from sumo_nets import load_net

SITUATIONS = ("junction_turn", "stopping", "bypass", "cruise")
EPISODE_FIX = "collect the dataset again into a new folder"
# one row per frame: the shape of a row (None: any size) of what the teacher and the student read
LABEL_ROWS = {"t": (), "x": (), "y": (), "yaw": (), "v": (), "path": (20, 2), "speed_wps": (10, 2),
              "target_point": (2,)}
# and what the renderer reads (Episode.scene)
SCENE_ROWS = {"lights": (None,), "stops": (None,), "props": (None, 5), "flag_stop": ()}
ACTOR_ROWS = {"actor_xy": (2,), "actor_yaw": (), "actor_speed": (), "actor_size": (2,), "actor_cls": ()}


def read_episode(path: Path, rows: dict[str, tuple] = LABEL_ROWS) -> dict[str, np.ndarray]:
    """Every array of the episode file ``path``, those of ``rows`` checked to hold one row per
    frame; BadInput naming the file and the fix if it is damaged (read_npz, check_rows)."""
    arrays = read_npz(path, "episode file", EPISODE_FIX)
    check_rows(arrays, rows, path, "episode file", EPISODE_FIX)
    return arrays


@lru_cache(maxsize=64)
def _plans(route_file: str) -> dict[str, GlobalPlan]:
    _, routes = read_routes(route_source(route_file))
    return {r.id: build_plan(r, load_net(r.town)) for r in routes}


def route_source(stored: str) -> Path:
    """The route file an episode's plan is read from: the path the episode stores
    (``route_file``, absolute, as ``collect`` was given it), or, when no file is there and
    that path named a shipped set (``.../scenarios/<set>.xml``: a dataset collected in
    another checkout or on another machine), that set in this installation. BadInput if
    neither exists."""
    path = Path(stored)
    if path.is_file():
        return path
    shipped = set_path(path.stem)
    if path.parent.name == shipped.parent.name and path.suffix == ".xml" and shipped.is_file():
        return shipped
    raise BadInput(f"route file {stored} of a recorded episode does not exist and names no shipped route set: "
                   "put the route file back at that path, or collect the dataset again")


class Episode:
    """One recorded route run (arrays as written by harness.expert.collect)."""

    def __init__(self, path: Path):
        self.a = read_episode(path)
        self.path = Path(path)
        if "stops" in self.a:  # else scene() names the old collection
            n = check_rows(self.a, SCENE_ROWS, path, "episode file", EPISODE_FIX, len(self))
            check_offsets(self.a, "actor_offset", ACTOR_ROWS, n, path, "episode file", EPISODE_FIX)
        missing = [k for k in ("town", "route_file", "route_id") if k not in self.a]
        if missing:
            raise BadInput(f"episode file {path} has no '{missing[0]}' array: {EPISODE_FIX}")
        self.town = str(self.a["town"])
        plans = _plans(str(self.a["route_file"]))
        if str(self.a["route_id"]) not in plans:
            raise BadInput(f"episode file {path}: route {self.a['route_id']} is not in its route file "
                           f"{self.a['route_file']}: {EPISODE_FIX}")
        self.plan = plans[str(self.a["route_id"])]

    def __len__(self) -> int:
        return len(self.a["t"])

    def scene(self, k: int) -> tuple[EgoState, Snapshot, list[int], list, list[bool]]:
        """What the renderer draws at frame k: ego, actors, light states, props, stop-sign states."""
        a = self.a
        if "stops" not in a:
            raise BadInput(f"{self.path} keeps no stop-sign state (collected before the BEV drew stop signs "
                           "until obeyed): collect the dataset again with this sumo-scimm")
        lo, hi = int(a["actor_offset"][k]), int(a["actor_offset"][k + 1])
        snap = Snapshot([""] * (hi - lo), a["actor_xy"][lo:hi], a["actor_yaw"][lo:hi], a["actor_speed"][lo:hi],
                        a["actor_size"][lo:hi], a["actor_cls"][lo:hi].astype(int), math.nan)
        props = [tuple(p) for p in a["props"][k] if np.isfinite(p).all()] if a["props"].size else []
        ego = EgoState(float(a["x"][k]), float(a["y"][k]), float(a["yaw"][k]), float(a["v"][k]))
        return ego, snap, [int(v) for v in a["lights"][k]], props, [bool(v) for v in a["stops"][k]]

    def bev(self, k: int, shift: float = 0.0, rot: float = 0.0) -> np.ndarray:
        """(9, 64, 64) uint8 BEV of frame k, seen from the ego moved by (shift [m] left, rot [rad])."""
        ego, snap, lights, props, stops = self.scene(k)
        if shift or rot:
            ego = EgoState(ego.x - math.sin(ego.yaw) * shift, ego.y + math.cos(ego.yaw) * shift,
                           ego.yaw + rot, ego.v)
        return BevRenderer.for_town(self.town).render(ego, snap, self.plan, lights, props, stops)

    def labels(self, k: int, shift: float = 0.0, rot: float = 0.0) -> dict[str, np.ndarray]:
        """Path (20, 2), speed waypoints (10, 2), target point (2,) in the (moved) ego frame."""
        c, s = math.cos(rot), math.sin(rot)

        def move(p):
            q = np.asarray(p, dtype=float) - (0.0, shift)
            return np.stack([c * q[..., 0] + s * q[..., 1], -s * q[..., 0] + c * q[..., 1]], -1)
        a = self.a
        return {"path": move(a["path"][k]), "speed_wps": move(a["speed_wps"][k]),
                "target_point": move(a["target_point"][k])}


def situation(row: pd.Series) -> str:
    """The frame's situation for ``data show`` (first that applies):
    junction_turn (in a junction with a left/right command), stopping (the expert's target
    is below 0.5 m/s, or 1 m/s below its speed), bypass (its path is shifted sideways),
    cruise."""
    if row["cue_junction"] > 0 and row["command"] in (1, 2):
        return "junction_turn"
    if row["target_speed"] < 0.5 or row["target_speed"] < row["v"] - 1.0:
        return "stopping"
    if row["cue_changed_route"] > 0:
        return "bypass"
    return "cruise"


INDEX_COLUMNS = ("t", "x", "y", "v", "command", "next_command", "target_speed", "cue_junction",
                 "cue_changed_route", "flag_vehicle", "flag_walker", "flag_light", "flag_stop")


def episode_files(folder: Path) -> list[Path]:
    """The dataset's episode files, sorted by name. BadInput if one has no record in the
    folder's records.jsonl (a collection stopped between saving an episode and recording
    its route: the episode is not known to be complete); a folder without records.jsonl
    (an episode set made by hand) is taken as it is."""
    import json
    files = sorted((Path(folder) / "episodes").glob("*.npz"))
    records = Path(folder) / "records.jsonl"
    if not records.is_file():
        return files
    keys = set()
    for line in records.read_text(errors="replace").splitlines():
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if isinstance(rec, dict) and isinstance(rec.get("key"), str):
            keys.add(rec["key"])
    unrecorded = [f.stem for f in files if f.stem not in keys]
    if unrecorded:
        raise BadInput(f"{folder}: episode {unrecorded[0]} has no record in records.jsonl (the collection was "
                       f"stopped): finish it with 'sumo-scimm collect ... --out {folder} --resume'")
    return files


def build_index(folder: Path, write: bool = True) -> pd.DataFrame:
    """One row per frame of every episode in ``folder/episodes`` (``episode_files``); written
    to index.csv unless ``write`` is False. BadInput naming a damaged episode file."""
    rows = []
    for ep in episode_files(folder):
        z = read_npz(ep, "episode file", EPISODE_FIX, (*INDEX_COLUMNS, "town", "route_id"))
        n = check_rows(z, dict.fromkeys(INDEX_COLUMNS, ()), ep, "episode file", EPISODE_FIX)
        df = pd.DataFrame({c: z[c] for c in INDEX_COLUMNS})
        df.insert(0, "frame", np.arange(n))
        df.insert(0, "town", str(z["town"]))
        df.insert(0, "route_id", str(z["route_id"]))
        df.insert(0, "episode", ep.stem)
        rows.append(df)
    index = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=["episode", "route_id", "town",
                                                                                   "frame", *INDEX_COLUMNS])
    if len(index):
        index["situation"] = index.apply(situation, axis=1)
    if write:
        write_atomic(folder / "index.csv", lambda tmp: index.to_csv(tmp, index=False))
    return index


def describe(index: pd.DataFrame) -> str:
    """``data show``: frames, hours driven, share of frames per situation, per town."""
    lines = [f"{'town':8} {'frames':>8} {'hours':>6}  " + "  ".join(f"{s:>13}" for s in SITUATIONS)]
    groups = [(t, g) for t, g in index.groupby("town")] + [("all", index)]
    for town, g in groups:
        share = g["situation"].value_counts(normalize=True) if len(g) else {}
        lines.append(f"{town:8} {len(g):8d} {len(g) / 4 / 3600:6.2f}  "
                     + "  ".join(f"{100 * share.get(s, 0.0):12.1f}%" for s in SITUATIONS))
    return "\n".join(lines)
