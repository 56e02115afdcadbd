"""The network: a small ResNet-style encoder per camera with a spatial softmax, a state MLP, and an
action-chunking MLP head that predicts K future actions at once (ACT's chunking, without its transformer).

Why this shape (measured on this 2-core CPU; see ``policy/__init__.py`` for the numbers):

- Per-camera encoders are not shared: head and wrist views look nothing alike; separate weights cost
  parameters, not time (each image passes one encoder either way).
- GroupNorm, not BatchNorm: batch statistics differ between a training batch and a single deployed
  observation, and Diffusion Policy's ResNets swap BN for GN for the same reason.
- Spatial softmax (Levine et al. 2016, used by robomimic / Diffusion Policy) turns each feature map into
  the expected image position of a learned keypoint: where the banana and the gripper are is what the
  actions depend on, and it keeps the feature vector small (2 x keypoints per camera).
- An MLP head instead of ACT's transformer decoder. Measured against an ACT-like head (the 6x6 feature-map
  cells of both cameras + a state token as memory, K learned queries, 2 decoder layers, d=128; 0.87 M
  parameters vs 0.30 M) on the demo's 12 episodes (9 train, 3 held out, 600 steps of 64): held-out L1
  0.244 (MLP) vs 0.277 (transformer); on grasp_banana after 80 steps, training L1 0.13 vs 0.37; and
  4.3-4.8 vs 3.3-4.1 steps/s. ACT's own decoder (7 layers, d=512) would cost far more on a CPU.
- 96 px and widths (16, 32, 64): 128 px gave held-out L1 0.240 (vs 0.244) at 20-40 % fewer steps/s, and
  widths (32, 64, 128) 0.245 at 30-50 % fewer, so neither pays for its time within a 30-minute budget.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..gaussians.losses import gaussian_window

__all__ = ["ModelSpec", "VisuomotorPolicy"]


@dataclass(frozen=True)
class ModelSpec:
    """Everything needed to rebuild the network (stored in the checkpoint).

    cameras      camera names, in input order
    image_size   square input side S (px)
    state_dim    entries of ``observation.state``
    action_dim   entries of ``action``
    chunk        K: future actions predicted per observation
    widths       encoder channels per resolution stage (stage i > 0 halves the resolution)
    keypoints    spatial-softmax keypoints per camera
    hidden       width of the state MLP and the head
    aux_dim      outputs of the auxiliary head (training only, from the cameras alone; 0: none)
    input_blur   sigma (px of the input) of a fixed Gaussian low-pass every image passes first, in training and
                 deployment alike: detail finer than the reconstruction renders (sharp spots on a real banana,
                 wood grain) is gone before the network sees it (0: none)
    """

    cameras: tuple[str, ...]
    image_size: int
    state_dim: int
    action_dim: int
    chunk: int
    widths: tuple[int, ...] = (16, 32, 64)
    keypoints: int = 32
    hidden: int = 256
    aux_dim: int = 0
    input_blur: float = 0.0

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> ModelSpec:
        d = dict(d)
        d["cameras"], d["widths"] = tuple(d["cameras"]), tuple(d["widths"])
        return cls(**d)


def _norm(c: int) -> nn.GroupNorm:
    return nn.GroupNorm(max(1, c // 16), c)


class _Block(nn.Module):
    """ResNet basic block (two 3x3 convs + skip) with GroupNorm."""

    def __init__(self, cin: int, cout: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.norm1 = _norm(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.norm2 = _norm(cout)
        self.skip = None
        if stride != 1 or cin != cout:
            self.skip = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), _norm(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.norm2(self.conv2(F.relu(self.norm1(self.conv1(x)))))
        return F.relu(y + (x if self.skip is None else self.skip(x)))


class SpatialSoftmax(nn.Module):
    """[B, C, h, w] -> [B, 2 * keypoints]: each keypoint's expected (x, y) in [-1, 1] under a softmax over
    the map of a 1x1-conv channel, with a learned temperature."""

    def __init__(self, channels: int, keypoints: int) -> None:
        super().__init__()
        self.proj = nn.Conv2d(channels, keypoints, 1)
        self.log_temperature = nn.Parameter(torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, _, h, w = x.shape
        logits = self.proj(x).flatten(2) / self.log_temperature.exp()  # [B, K, h*w]
        p = logits.softmax(-1)
        ys = torch.linspace(-1, 1, h, device=x.device, dtype=p.dtype)
        xs = torch.linspace(-1, 1, w, device=x.device, dtype=p.dtype)
        gy, gx = torch.meshgrid(ys, xs, indexing="ij")
        kx = (p * gx.reshape(1, 1, -1)).sum(-1)
        ky = (p * gy.reshape(1, 1, -1)).sum(-1)
        return torch.cat([kx, ky], -1)


class Encoder(nn.Module):
    """uint8-derived float image [B, 3, S, S] in [0, 1] -> [B, 2 * keypoints].

    A stride-4 stem (two stride-2 3x3 convs) then one basic block per stage, stage i > 0 at stride 2: a 96 px
    image ends at 6 x 6 x 64 with widths (16, 32, 64); the softmax-weighted mean position of each keypoint is
    finer than a cell."""

    def __init__(self, widths: tuple[int, ...], keypoints: int, input_blur: float = 0.0) -> None:
        super().__init__()
        # fixed 1-D taps out to 3 sigma (the 2-D blur is separable: rows, then columns); not learned and not in the
        # state dict (rebuilt from the spec), so older checkpoints load unchanged
        taps = gaussian_window(2 * max(1, math.ceil(3 * input_blur)) + 1, input_blur) if input_blur > 0 else None
        self.register_buffer("blur", taps, persistent=False)
        c0 = widths[0]
        layers: list[nn.Module] = [
            nn.Conv2d(3, c0, 3, 2, 1, bias=False), _norm(c0), nn.ReLU(inplace=True),
            nn.Conv2d(c0, c0, 3, 2, 1, bias=False), _norm(c0), nn.ReLU(inplace=True),
        ]  # fmt: skip
        cin = c0
        for i, w in enumerate(widths):
            layers.append(_Block(cin, w, 1 if i == 0 else 2))
            cin = w
        self.trunk = nn.Sequential(*layers)
        self.pool = SpatialSoftmax(cin, keypoints)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.blur is not None:
            k = self.blur.to(x.dtype)
            r = k.shape[0] // 2
            x = F.pad(x, (r, r, r, r), mode="replicate")
            x = F.conv2d(x, k.view(1, 1, 1, -1).expand(3, 1, 1, -1), groups=3)  # rows
            x = F.conv2d(x, k.view(1, 1, -1, 1).expand(3, 1, -1, 1), groups=3)  # columns
        return self.pool(self.trunk(x * 2.0 - 1.0))


class VisuomotorPolicy(nn.Module):
    """(images {camera: float [B, 3, S, S] in [0, 1]}, normalised state [B, S_dim]) -> normalised action
    chunk [B, K, A]."""

    def __init__(self, spec: ModelSpec) -> None:
        super().__init__()
        self.spec = spec
        self.encoders = nn.ModuleDict({c: Encoder(spec.widths, spec.keypoints, spec.input_blur) for c in spec.cameras})
        self.state_mlp = nn.Sequential(nn.Linear(spec.state_dim, spec.hidden // 4), nn.ReLU(inplace=True))
        feat = len(spec.cameras) * 2 * spec.keypoints + spec.hidden // 4
        self.head = nn.Sequential(
            nn.Linear(feat, spec.hidden), nn.LayerNorm(spec.hidden), nn.ReLU(inplace=True),
            nn.Linear(spec.hidden, spec.hidden), nn.ReLU(inplace=True),
            nn.Linear(spec.hidden, spec.chunk * spec.action_dim),
        )  # fmt: skip
        self.aux_head = None
        if spec.aux_dim:  # what the cameras must tell without the state (see policy.targets)
            n_img = len(spec.cameras) * 2 * spec.keypoints
            self.aux_head = nn.Sequential(nn.Linear(n_img, spec.hidden), nn.ReLU(inplace=True),
                                          nn.Linear(spec.hidden, spec.aux_dim))  # fmt: skip

    def forward(
        self, images: dict[str, torch.Tensor], state: torch.Tensor, with_aux: bool = False
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Action chunk [B, K, A]; with ``with_aux`` also the auxiliary head's output [B, aux_dim]."""
        feats = torch.cat([self.encoders[c](images[c]) for c in self.spec.cameras], -1)
        h = torch.cat([feats, self.state_mlp(state)], -1)
        actions = self.head(h).view(-1, self.spec.chunk, self.spec.action_dim)
        if not with_aux:
            return actions
        if self.aux_head is None:
            raise ValueError("this policy has no auxiliary head (aux_dim 0)")
        return actions, self.aux_head(feats)
