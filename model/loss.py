"""The training loss of the SC-IMM paper, eq. 10-13 (docs/design.md §7).

    L = l_origin * L_origin + l_scimm * L_scimm + l_mode * L_mode            (eq. 10)
    L_origin = MSE(P^, P) + MSE(W^, W)              expert path and speed waypoints
    L_scimm  = ||P^ - P^T||^2 + ||phi(W^) - V^T||^2                          (eq. 11)
    phi(W^)^k = ||w^k - w^(k-1)|| / dt,  dt = 0.25 s                        (eq. 12)
    L_mode   = KL(mu^T || softmax(mode logits))                              (eq. 13)

Symbols (B = batch), all in the label frame (ego frame x forward, y left, moved by the
sample's augmentation, see model.data):

| name | shape | unit | meaning |
| --- | --- | --- | --- |
| P^, P | (B, 20, 2) | m | predicted / expert path at arc length 0..19 m |
| W^, W | (B, 10, 2) | m | predicted / expert speed waypoints at 0.25..2.5 s |
| origin | (B, 2) | m | the ego's position at t = 0 (w^0 of eq. 12); (0, 0) without augmentation |
| P^T | (B, 20, 2) | m | path teacher |
| V^T | (B, 10) | m/s | speed teacher at tau = 0.25..2.5 s |
| mu^T | (B, 5) | - | teacher mode posterior [Cruise, Turn, Deceleration, Avoidance, Recovery] |

The teacher symbols per ``--teacher`` (model.data):

| teacher | P^T | V^T | mu^T |
| --- | --- | --- | --- |
| none (baseline) | - | - | - (l_scimm = l_mode = 0) |
| control | P (the expert path) | phi(W) (the expert's own speeds) | 1/5 each (constant) |
| fixed, scimm, smoother | the teacher's path | the teacher's speeds | the teacher's posterior |

Normalisation (the paper gives none): as SimLingo-Base's MSE, a squared point distance is
summed over x, y and averaged over the points of a sequence, then over the batch; the speed
term of eq. 11 is averaged over its 10 speeds. KL is in nats, averaged over the batch.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

SPEED_DT = 0.25  # time between speed waypoints [s] (4 Hz)


@dataclass(frozen=True)
class LossWeights:
    """lambda_origin, lambda_scimm, lambda_mode of eq. 10 (the paper does not publish values)."""

    origin: float = 1.0
    scimm: float = 1.0  # teacher terms on the same footing as the expert terms
    mode: float = 0.1  # auxiliary: shapes the shared representation, must not dominate it

    def __post_init__(self) -> None:
        if not all(math.isfinite(w) and w >= 0 for w in (self.origin, self.scimm, self.mode)):
            raise ValueError(f"loss weights must be finite and >= 0, got {self}")


BASELINE = LossWeights(scimm=0.0, mode=0.0)


def phi(wps: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """Speeds (B, K) [m/s] between consecutive speed waypoints wps (B, K, 2) [m], starting
    from origin (B, 2) [m], the ego's position at t = 0 in the same frame."""
    prev = torch.cat([origin.unsqueeze(1), wps[:, :-1]], dim=1)  # (B, K, 2): w^(k-1)
    return torch.linalg.vector_norm(wps - prev, dim=-1) / SPEED_DT  # paper eq. 12


def point_mse(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Squared distance (B, N, 2) -> summed over x, y, averaged over points and batch [m^2]."""
    return (pred - target).pow(2).sum(-1).mean()


def origin_loss(pred: dict, batch: dict) -> dict[str, torch.Tensor]:
    """L_origin terms: expert path and speed waypoints [m^2]."""
    return {"path": point_mse(pred["path"], batch["path"]),
            "speed_wps": point_mse(pred["speed_wps"], batch["speed_wps"])}


def scimm_loss(pred: dict, batch: dict) -> dict[str, torch.Tensor]:
    """L_scimm terms: path teacher [m^2] and speed teacher [(m/s)^2]."""
    # paper eq. 11
    return {"teacher_path": point_mse(pred["path"], batch["teacher_path"]),
            "teacher_speed": (phi(pred["speed_wps"], batch["origin"]) - batch["teacher_speed"]).pow(2).mean()}


def mode_loss(logits: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
    """KL(mu || softmax(logits)) [nats], batch mean; 0 log 0 = 0."""
    # paper eq. 13
    return (torch.xlogy(mu, mu) - mu * F.log_softmax(logits, dim=-1)).sum(-1).mean()


def total_loss(pred: dict, batch: dict, w: LossWeights) -> dict[str, torch.Tensor]:
    """Every term by name plus ``loss`` (eq. 10). Teacher terms are computed only when
    their weight is > 0, so a baseline batch needs no teacher fields."""
    terms = origin_loss(pred, batch)
    loss = w.origin * (terms["path"] + terms["speed_wps"])
    if w.scimm > 0:
        terms.update(scimm_loss(pred, batch))
        loss = loss + w.scimm * (terms["teacher_path"] + terms["teacher_speed"])
    if w.mode > 0:
        terms["mode"] = mode_loss(pred["mode_logits"], batch["mu"])
        loss = loss + w.mode * terms["mode"]
    terms["loss"] = loss  # paper eq. 10
    return terms
