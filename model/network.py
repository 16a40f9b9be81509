"""The student: a small network in the shape of SimLingo-BASE (CarLLaVA), sized for a CPU (docs/design.md §7).

References: Renz et al., "CarLLaVA" / SimLingo-Base (docs/design.md §7); Kim & Kong,
SC-IMM paper §4 (auxiliary mode predictor).

Data flow (B = batch)::

    bev (B, 9, 64, 64) in {0, 1}  --CNN-->  visual tokens (B, 64, D)     (8 x 8 grid, + position)
    target point (B, 2) [m], ego frame  --MLP-->  1 conditioning token    (B, 1, D)
    speed (B,) [m/s]                    --MLP-->  1 conditioning token    (B, 1, D)
        (NetConfig.speed_input False, the default: the MLP sees 0, so the token is a
        learned constant and the plan depends on the BEV and target point only; the
        inertia problem of a student that sees its own speed, docs/student.md)
    20 learned path queries + 10 learned speed queries                    (B, 30, D)
    [conditioning | queries] --transformer decoder, cross-attending to the visual tokens-->
                                                              query outputs (B, 30, D)
    path head:  (B, 20, D) -> 2-D increments -> cumulative sum -> path (B, 20, 2)
    speed head: (B, 10, D) -> 2-D increments -> cumulative sum -> speed waypoints (B, 10, 2)
    mode head:  mean over the 30 query outputs -> 5 logits (used only in the loss)

Outputs are in the ego frame (x forward, y left) [m]: path points meant to lie at arc length
0, 1, ..., 19 m; speed waypoints = future positions at 0.25, 0.5, ..., 2.5 s. The mode
logits are in mode order [Cruise, Turn, Deceleration, Avoidance, Recovery].

SimLingo-Base runs a causal LLaMA decoder over [visual | conditioning | queries]; here the
conditioning tokens and queries attend to each other and cross-attend to the visual tokens
(a pre-norm transformer decoder). Same information flow for the queries, at about half the
cost of self-attention over all 96 tokens on a CPU (measured: 153 vs 299 ms CPU per
fwd+bwd of 128 samples).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

MODES = ("Cruise", "Turn", "Deceleration", "Avoidance", "Recovery")


@dataclass(frozen=True)
class NetConfig:
    """Architecture of the student; stored in every model checkpoint."""

    in_channels: int = 9  # BEV channels (harness.sensors.bev.CHANNELS)
    bev_size: int = 64  # BEV side [px]
    width: int = 16  # channels of the first conv stage (the second has 2x, the third D)
    d_model: int = 64  # token width D
    n_heads: int = 4
    n_layers: int = 2
    d_ffn: int = 128  # transformer feed-forward width
    n_path: int = 20  # path queries (1 m apart)
    n_speed: int = 10  # speed queries (0.25 s apart)
    n_modes: int = 5  # len(MODES)
    target_scale: float = 20.0  # target point divided by this [m] before its MLP (median 18 m)
    speed_scale: float = 10.0  # speed divided by this [m/s] before its MLP
    speed_input: bool = False  # True: the ego speed conditions the queries (see docs/student.md)

    def __post_init__(self) -> None:
        if self.bev_size % 8:
            raise ValueError(f"bev_size must be a multiple of 8, got {self.bev_size}")
        if self.d_model % self.n_heads:
            raise ValueError(f"d_model {self.d_model} is not divisible by n_heads {self.n_heads}")

    def to_dict(self) -> dict:
        return asdict(self)


def _mlp(d_in: int, d_hidden: int, d_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(d_in, d_hidden), nn.ReLU(), nn.Linear(d_hidden, d_out))


class BevEncoder(nn.Module):
    """CNN: (B, C, S, S) -> (B, (S/8)^2, D) visual tokens with learned position embeddings."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        w, d = cfg.width, cfg.d_model
        self.cnn = nn.Sequential(
            nn.Conv2d(cfg.in_channels, w, 4, stride=4), nn.ReLU(),  # (B, w, S/4, S/4): 3 m cells
            nn.Conv2d(w, 2 * w, 3, stride=2, padding=1), nn.ReLU(),  # (B, 2w, S/8, S/8): 6 m cells
            nn.Conv2d(2 * w, d, 3, padding=1),  # (B, D, S/8, S/8): 28 px (21 m) receptive field
        )
        self.pos = nn.Parameter(torch.zeros(1, (cfg.bev_size // 8) ** 2, d))

    def forward(self, bev: torch.Tensor) -> torch.Tensor:
        # channels-last memory: the same layers (outputs and gradients equal up to float32
        # rounding), and on a CPU the first convolution's backward pass costs a seventh of
        # what it costs on (B, C, H, W) memory (training steps 71 -> 61 ms at batch 128)
        x = self.cnn(bev.contiguous(memory_format=torch.channels_last))  # (B, D, 8, 8)
        return x.flatten(2).transpose(1, 2) + self.pos  # (B, 64, D)


class Attention(nn.Module):
    """Multi-head attention of x (B, T, D) to context (B, S, D) (context = x: self-attention).

    Written out (one fused projection each for q and k, v) because torch's
    nn.MultiheadAttention costs ~0.25 ms per call at batch 1 on this CPU, 3x this module."""

    def __init__(self, d: int, n_heads: int):
        super().__init__()
        self.n_heads = n_heads
        self.q = nn.Linear(d, d)
        self.kv = nn.Linear(d, 2 * d)
        self.out = nn.Linear(d, d)

    def forward(self, x: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        b, t, d = x.shape
        s, h = context.shape[1], self.n_heads
        q = self.q(x).view(b, t, h, d // h).transpose(1, 2)  # (B, h, T, D/h)
        k, v = self.kv(context).view(b, s, 2, h, d // h).permute(2, 0, 3, 1, 4).unbind(0)  # 2 x (B, h, S, D/h)
        y = F.scaled_dot_product_attention(q, k, v)  # (B, h, T, D/h)
        return self.out(y.transpose(1, 2).reshape(b, t, d))  # (B, T, D)


class DecoderBlock(nn.Module):
    """Pre-norm transformer decoder block: self-attention, cross-attention to the visual
    tokens, feed-forward; each added to the residual stream x (B, T, D)."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        d = cfg.d_model
        self.norm1, self.norm2, self.norm3 = nn.LayerNorm(d), nn.LayerNorm(d), nn.LayerNorm(d)
        self.self_attn = Attention(d, cfg.n_heads)
        self.cross_attn = Attention(d, cfg.n_heads)
        self.ffn = _mlp(d, cfg.d_ffn, d)

    def forward(self, x: torch.Tensor, memory: torch.Tensor) -> torch.Tensor:
        h = self.norm1(x)
        x = x + self.self_attn(h, h)
        x = x + self.cross_attn(self.norm2(x), memory)
        return x + self.ffn(self.norm3(x))


class Student(nn.Module):
    """BEV + target point + speed -> path (B, 20, 2), speed waypoints (B, 10, 2), mode logits (B, 5)."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.bev = BevEncoder(cfg)
        self.target_in = _mlp(2, d, d)
        self.speed_in = _mlp(1, d, d)
        self.queries = nn.Parameter(torch.zeros(1, cfg.n_path + cfg.n_speed, d))
        self.blocks = nn.ModuleList(DecoderBlock(cfg) for _ in range(cfg.n_layers))
        self.norm = nn.LayerNorm(d)
        self.path_head = _mlp(d, d, 2)
        self.speed_head = _mlp(d, d, 2)
        self.mode_head = nn.Linear(d, cfg.n_modes)
        self._init_weights()

    def _init_weights(self) -> None:
        """Small random position embeddings and queries (zeros would make all queries equal)."""
        nn.init.normal_(self.bev.pos, std=0.02)
        nn.init.normal_(self.queries, std=0.02)

    def forward(self, bev: torch.Tensor, target_point: torch.Tensor, speed: torch.Tensor) -> dict[str, torch.Tensor]:
        """bev (B, 9, 64, 64) float in {0, 1}; target_point (B, 2) [m] ego frame; speed (B,) [m/s]."""
        cfg = self.cfg
        b = bev.shape[0]
        vis = self.bev(bev)  # (B, 64, D)
        tp = self.target_in(target_point / cfg.target_scale).unsqueeze(1)  # (B, 1, D)
        if not cfg.speed_input:
            speed = torch.zeros_like(speed)
        sp = self.speed_in(speed.unsqueeze(-1) / cfg.speed_scale).unsqueeze(1)  # (B, 1, D)
        q = self.queries.expand(b, -1, -1)  # (B, 30, D)
        x = torch.cat([tp, sp, q], dim=1)  # (B, 2 + 30, D)
        for block in self.blocks:
            x = block(x, vis)  # attending to each other and to vis (B, 64, D)
        out = self.norm(x[:, -(cfg.n_path + cfg.n_speed):])  # (B, 30, D) query outputs
        path_q, speed_q = out[:, :cfg.n_path], out[:, cfg.n_path:]
        # paper eq. 1: the prediction Y^ = {P^, V^}, a path and speed waypoints (V^ = phi(W^), eq. 12)
        return {
            "path": torch.cumsum(self.path_head(path_q), dim=1),  # (B, 20, 2) [m]
            "speed_wps": torch.cumsum(self.speed_head(speed_q), dim=1),  # (B, 10, 2) [m]
            "mode_logits": self.mode_head(out.mean(dim=1)),  # (B, 5)
        }


def n_params(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
