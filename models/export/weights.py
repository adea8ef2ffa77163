"""Loading a reference model's weights for export: one state dict, strictly, on the CPU."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import torch
from torch import nn

M = TypeVar("M", bound=nn.Module)


def load_strict(model: M, weights: Path) -> M:
    """`model` with the state dict at `weights` (a plain tensor file, no pickled code) loaded
    strictly (every key, no extra), in eval mode."""
    state = torch.load(weights, map_location="cpu", weights_only=True)
    model.load_state_dict(state, strict=True)
    return model.eval()
