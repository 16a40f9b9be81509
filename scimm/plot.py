"""Paper Fig. 4 for one episode: the BEV of a few frames (top) and the five SC-IMM mode
posteriors over time (bottom), with the shown frames marked.

The posterior is recomputed for the episode alone (scimm.teacher.teach with the default
config); it equals the row of ``DIR/teacher/scimm`` for the same config, because every
episode is filtered independently.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from files.atomic import write_atomic
from scimm.modes import MODES, IMMConfig
from scimm.teacher import teach

N_FRAMES = 4  # BEV panels
COLOURS = ("tab:blue", "tab:orange", "tab:red", "tab:purple", "tab:green")  # in MODES order


def plot_posterior(episode_file: Path, out: Path, method: str = "scimm", cfg: IMMConfig | None = None) -> Path:
    """Write the figure for ``episode_file`` to ``out`` (.png, written atomically)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from harness.sensors.bev import colorize
    from harness.expert.dataset import Episode

    cfg = cfg or IMMConfig()
    mu = teach([Path(episode_file)], method, cfg)[Path(episode_file).stem]["mu"]
    ep = Episode(Path(episode_file))
    t = ep.a["t"]
    frames = np.linspace(0, len(t) - 1, N_FRAMES + 2).round().astype(int)[1:-1]
    fig = plt.figure(figsize=(12, 7))
    grid = fig.add_gridspec(2, N_FRAMES, height_ratios=(1.1, 1.0))
    for col, k in enumerate(frames):
        ax = fig.add_subplot(grid[0, col])
        ax.imshow(colorize(ep.bev(int(k)))[..., ::-1])  # BGR -> RGB
        dom = MODES[int(np.argmax(mu[k]))]
        ax.set_title(f"({chr(97 + col)}) t = {t[k]:.1f} s: {dom}", fontsize=9)
        ax.axis("off")
    ax = fig.add_subplot(grid[1, :])
    for j, name in enumerate(MODES):
        ax.plot(t, mu[:, j], color=COLOURS[j], label=name, lw=1.5)
    for col, k in enumerate(frames):
        ax.axvline(t[k], color="grey", lw=0.8, ls="--")
        ax.text(t[k], 1.02, f"({chr(97 + col)})", ha="center", fontsize=8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("mode posterior")
    ax.set_ylim(0, 1.08)
    ax.set_xlim(t[0], t[-1])
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=5, fontsize=8)
    from scimm.table2 import ROW_NAMES
    fig.suptitle(f"{ROW_NAMES[method]} mode posterior, episode {Path(episode_file).stem}")
    fig.tight_layout()
    out = Path(out)
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    return out
