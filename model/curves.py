"""Loss curves of trained students: one figure, every arm (``sumo-scimm train curves``).

    sumo-scimm train curves --runs baseline=runs/student_baseline scimm=runs/student_scimm --out curves.png

Each arm's curves come from its training folder's ``history.json`` (model.train; a folder
trained before that file existed falls back to the ``history`` of its ``manifest.json``).
Three panels, x = epoch: the validation path loss and the validation speed-waypoint loss
(the two terms of L_origin on the validation set [m^2], the criterion that chooses the epoch saved,
the same for every arm) and the training loss (eq. 10 with the arm's own weights, so its
level differs between arms; its shape is what to compare). The chosen epoch, whose weights
the checkpoint holds, is a ring on each curve: the manifest's ``chosen_epoch``, or for a
folder without one, the last epoch (what the training saved then).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from files.atomic import write_atomic
from harness.common.errors import BadInput
from model.checkpoint import HISTORY_NAME

PANELS = (("val", "path", "validation path loss [m^2]"), ("val", "speed_wps", "validation speed-waypoint loss [m^2]"),
          ("train", "loss", "training loss (eq. 10, the arm's weights)"))


@dataclass(frozen=True)
class Curves:
    """One arm's per-epoch losses: ``epochs`` (1-based), ``val`` and ``train`` term -> values."""

    epochs: list[int]
    val: dict[str, list[float]]
    train: dict[str, list[float]]
    chosen_epoch: int


def load_history(path: Path) -> Curves:
    """The curves of a training folder (its history.json, else manifest.json) or of a
    history.json/manifest.json file; BadInput (one line) if there is none or it is malformed."""
    path = Path(path)
    files = [path / HISTORY_NAME, path / "manifest.json"] if path.is_dir() else [path]
    found = next((f for f in files if f.is_file()), None)
    if found is None:
        raise BadInput(f"no training history in {path} (expected {HISTORY_NAME} or manifest.json of "
                       f"'sumo-scimm train --out {path}')")
    try:
        h = json.loads(found.read_text())
        records = h["history"]
        epochs = [int(r["epoch"]) for r in records]
        val = {k: [float(r["val"][k]) for r in records] for k in ("path", "speed_wps")} \
            if records and all("val" in r for r in records) else {}
        train = {k: [float(r["train"][k]) for r in records] for k in records[0]["train"]} if records else {}
        chosen = h.get("chosen_epoch")
    except (OSError, ValueError, KeyError, TypeError, AttributeError, OverflowError, RecursionError) as exc:
        raise BadInput(f"{found} is not a training history ({type(exc).__name__}: {str(exc)[:80]}); use the folder "
                       "of a 'sumo-scimm train' run") from None
    if not epochs:
        raise BadInput(f"{found} holds no epoch; use the folder of a finished 'sumo-scimm train' run")
    if isinstance(chosen, float) and chosen.is_integer():
        chosen = int(chosen)  # 3.0: the same epoch
    if chosen is not None and (isinstance(chosen, bool) or not isinstance(chosen, int)):
        raise BadInput(f"{found}: chosen_epoch is {repr(chosen)[:40]}, not an epoch number: the file is damaged; "
                       "use the folder of a 'sumo-scimm train' run")
    chosen = chosen or epochs[-1]
    if chosen not in epochs:
        raise BadInput(f"{found}: chosen epoch {chosen} is not among its epochs {epochs[0]}..{epochs[-1]}")
    return Curves(epochs, val, train, chosen)


def plot_loss_curves(histories: dict[str, Path], out: Path) -> Path:
    """One PNG at ``out``: the PANELS above for every arm (arm name -> training folder or
    its history.json), the chosen epoch ringed. Returns ``out``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not histories:
        raise BadInput("no training to plot: give at least one ARM=DIR")
    fig = draw_loss_curves({arm: load_history(path) for arm, path in histories.items()})
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    return out


def draw_loss_curves(curves: dict[str, Curves]):
    """The figure of plot_loss_curves (a matplotlib Figure); the ring of an arm's chosen
    epoch is the line with gid ``chosen:<arm>`` in each panel."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(PANELS), figsize=(4.6 * len(PANELS), 3.8))
    for ax, (part, term, title) in zip(axes, PANELS):
        for arm, c in curves.items():
            ys = getattr(c, part).get(term)
            if not ys:
                continue  # no validation set in that training
            (line,) = ax.plot(c.epochs, ys, "-o", ms=3, label=arm)
            k = c.epochs.index(c.chosen_epoch)
            ax.plot([c.chosen_epoch], [ys[k]], "o", ms=10, mfc="none", color=line.get_color(), gid=f"chosen:{arm}")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("epoch")
    axes[0].legend(fontsize=7)
    fig.suptitle("Student loss curves (ring: the chosen epoch, whose weights are saved)", fontsize=10)
    fig.tight_layout()
    return fig
