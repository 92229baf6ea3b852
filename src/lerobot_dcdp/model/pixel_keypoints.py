"""An object-keypoint reader from pixels: one camera frame -> the object's keypoints, in their raw units.

The image path of DCDP: the correction, the training-free anchoring, the completion gate and the scene lead
all read the object's keypoints and what changed since the plan. A camera robot has no keypoints at run time,
so this small network estimates them from the frame; it is trained once, on frames whose keypoints were known
at training time (a simulator's, a motion-capture's), and frozen. Sub-pixel position is what matters (at
96x96 a 2 px/step PushT drift moves the block 0.375 image px per frame), so the trunk keeps half the input
resolution and reads position through a spatial soft-argmax (LeRobot's :class:`SpatialSoftmax`, as its
diffusion policy's image encoder does), not through pooling.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from lerobot.policies.diffusion.modeling_diffusion import SpatialSoftmax
from torch import Tensor, nn

#: the files of a reader's folder (``dcdp-fit-pixel-keypoints --out``)
CONFIG_NAME = "config.json"
WEIGHTS_NAME = "model.safetensors"
FIT_NAME = "fit.json"


@dataclass
class PixelKeypointsConfig:
    """The architecture of :class:`PixelKeypointNet` (saved beside its weights).

    Args:
        image_shape: (C, H, W) of the frames it reads, values in [0, 1].
        n_outputs: Width of the keypoint vector it returns (PushT: 8 keypoints x 2 = 16).
        channels: Output channels of the trunk's three 3x3 convolutions (the first has stride 2).
        n_maps: Spatial soft-argmax maps (each gives one expected (x, y) in the frame).
        hidden_dim: Width of the MLP from the soft-argmax points to the keypoints.
    """

    image_shape: tuple[int, int, int] = (3, 96, 96)
    n_outputs: int = 16
    channels: tuple[int, ...] = (16, 32, 32)
    n_maps: int = 32
    hidden_dim: int = 256
    #: filled by the fit: raw = standardised * scale + shift, per output
    shift: list[float] = field(default_factory=list)
    scale: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.image_shape = tuple(int(x) for x in self.image_shape)
        self.channels = tuple(int(x) for x in self.channels)
        if len(self.image_shape) != 3 or min(self.image_shape) < 1:
            raise ValueError(f"image_shape must be (C, H, W) with positive sizes, got {self.image_shape}")
        if self.n_outputs < 1 or self.n_maps < 1 or self.hidden_dim < 1:
            raise ValueError(
                f"n_outputs, n_maps and hidden_dim must be >= 1, got {self.n_outputs}, {self.n_maps}, "
                f"{self.hidden_dim}"
            )
        if len(self.channels) < 1 or min(self.channels) < 1:
            raise ValueError(f"channels must be a non-empty list of positive widths, got {self.channels}")
        for name in ("shift", "scale"):
            values = getattr(self, name)
            if values and len(values) != self.n_outputs:
                raise ValueError(f"{name} must have n_outputs={self.n_outputs} values, got {len(values)}")

    def to_dict(self) -> dict:
        """JSON-ready fields."""
        d = asdict(self)
        d["image_shape"], d["channels"] = list(self.image_shape), list(self.channels)
        return d


class PixelKeypointNet(nn.Module):
    """Frames ``(*lead, C, H, W)`` in [0, 1] -> keypoints ``(*lead, n_outputs)`` in raw units.

    Trunk: 3x3 convolutions (the first with stride 2, so the maps are H/2 x W/2) with GroupNorm and ReLU;
    then LeRobot's spatial soft-argmax (``n_maps`` expected points in [-1, 1]) and an MLP to the standardised
    keypoints, de-standardised with the ``shift`` / ``scale`` buffers the fit stores.
    """

    def __init__(self, config: PixelKeypointsConfig) -> None:
        super().__init__()
        self.config = config
        c, h, w = config.image_shape
        layers: list[nn.Module] = []
        for i, out in enumerate(config.channels):
            layers += [
                nn.Conv2d(c, out, 3, stride=2 if i == 0 else 1, padding=1),
                nn.GroupNorm(min(8, out), out),
                nn.ReLU(),
            ]
            c = out
        self.trunk = nn.Sequential(*layers)
        maps_hw = ((h + 1) // 2, (w + 1) // 2)
        self.pool = SpatialSoftmax((c, *maps_hw), num_kp=config.n_maps)
        self.head = nn.Sequential(
            nn.Linear(2 * config.n_maps, config.hidden_dim),
            nn.ReLU(),
            nn.Linear(config.hidden_dim, config.n_outputs),
        )
        shift = torch.tensor(config.shift or [0.0] * config.n_outputs, dtype=torch.float32)
        scale = torch.tensor(config.scale or [1.0] * config.n_outputs, dtype=torch.float32)
        self.register_buffer("shift", shift)
        self.register_buffer("scale", scale)

    def standardised(self, img: Tensor) -> Tensor:
        """Frames -> standardised keypoints (what the fit regresses)."""
        lead = img.shape[:-3]
        x = img.reshape(-1, *img.shape[-3:])
        points = self.pool(self.trunk(x)).flatten(1)
        return self.head(points).reshape(*lead, self.config.n_outputs)

    def forward(self, img: Tensor) -> Tensor:
        """Frames -> keypoints in raw units."""
        return self.standardised(img) * self.scale + self.shift


def keypoint_error(pred: Tensor, target: Tensor) -> Tensor:
    """Mean Euclidean distance per (x, y) pair between two keypoint vectors ``(..., 2N)`` (pure)."""
    if pred.shape != target.shape or pred.shape[-1] % 2:
        raise ValueError(f"keypoint vectors must match and be (..., 2N), got {pred.shape} / {target.shape}")
    diff = (pred - target).reshape(*pred.shape[:-1], -1, 2)
    return diff.norm(dim=-1).mean()


def load_reader(path: str | Path) -> tuple[PixelKeypointNet, str, str]:
    """A reader saved by ``dcdp-fit-pixel-keypoints`` (eval mode), with its image and target keys.

    Raises:
        ValueError: ``path`` holds no reader.
    """
    from safetensors.torch import load_file

    path = Path(path)
    if not (path / CONFIG_NAME).is_file() or not (path / WEIGHTS_NAME).is_file():
        raise ValueError(f"{path} holds no pixel-keypoint reader ({CONFIG_NAME} + {WEIGHTS_NAME})")
    config = json.loads((path / CONFIG_NAME).read_text())
    image_key, target_key = config.pop("image_key"), config.pop("target_key")
    net = PixelKeypointNet(PixelKeypointsConfig(**config))
    net.load_state_dict(load_file(str(path / WEIGHTS_NAME)))
    return net.eval(), image_key, target_key
