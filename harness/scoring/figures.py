"""Paper Fig. 5: consecutive waypoint outputs of several agents on the same stretch of a
route, overlaid in the world frame, one panel per agent (from the eval logs; nothing is
re-simulated).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from files.atomic import write_atomic
from harness.common.errors import BadInput

LOG_ROWS = {"steer": (), "x": (), "y": (), "yaw": (), "pred_path": (None, 2)}  # what the overlay reads


def _world(points: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    """Ego-frame points (x forward, y left) [m] -> world frame."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([x + c * points[:, 0] - s * points[:, 1], y + s * points[:, 0] + c * points[:, 1]], 1)


def waypoint_overlay(runs: dict[str, Path], route_key: str, out: Path, radius: float = 12.0,
                     every: int = 4) -> Path:
    """Draw the predicted paths of every ``every``-th tick (0.05 s each) while each run's ego
    is within ``radius`` m of the point where the first run steered hardest on route
    ``route_key`` (a junction turn or an evasive move: where stability shows). PNG in ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from harness.common.npz import check_rows, read_npz
    logs = {}
    for name, folder in runs.items():
        fix = f"evaluate run {folder} again, or leave it out of --runs"
        path = Path(folder) / "logs" / f"{route_key}.npz"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no log of route {route_key} in run {folder}")
        logs[name] = read_npz(path, "log", fix, LOG_ROWS)
        if not check_rows(logs[name], LOG_ROWS, path, "log", fix):
            raise BadInput(f"log {path} holds no tick: {fix}")
    first = next(iter(logs.values()))
    k = int(np.argmax(np.abs(first["steer"])))
    centre = np.array([first["x"][k], first["y"][k]])
    fig, axes = plt.subplots(1, len(logs), figsize=(4.2 * len(logs), 4.2), squeeze=False)
    for ax, (name, log) in zip(axes[0], logs.items()):
        near = np.flatnonzero(np.hypot(log["x"] - centre[0], log["y"] - centre[1]) < radius)[::every]
        colours = plt.cm.viridis(np.linspace(0, 1, max(len(near), 1)))
        for c, t in zip(colours, near):
            p = _world(log["pred_path"][t], log["x"][t], log["y"][t], log["yaw"][t])
            ax.plot(p[:, 0], p[:, 1], "-", color=c, lw=0.8, alpha=0.8)
        ax.plot(log["x"], log["y"], "k--", lw=0.8, label="driven")
        ax.set_xlim(centre[0] - radius - 20, centre[0] + radius + 20)
        ax.set_ylim(centre[1] - radius - 20, centre[1] + radius + 20)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: {len(near)} outputs, every {every * 0.05:.2f} s")
        ax.set_xlabel("x [m]")
    axes[0][0].set_ylabel("y [m]")
    axes[0][0].legend(loc="lower left", fontsize=7)
    fig.suptitle(f"Consecutive predicted paths, route {route_key} (colour: time)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    return out
