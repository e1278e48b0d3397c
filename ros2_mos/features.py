"""The network input: which channels a model takes and how they are assembled.

The paper's ablation feeds the CNN either frames (5 channels each: r, x, y, z, e)
or the current frame plus N residual images (5 + N channels).  The setup and the
normalisation travel with the model (see :mod:`ros2_mos.metadata`), so the
pipeline builds exactly what the network was trained on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.errors import ConfigError
from ros2_mos.projection import RangeImage

# LiDAR-MOS / SalsaNext's SemanticKITTI statistics for (r, x, y, z, e).
DEFAULT_MEANS = (12.12, 10.88, 0.23, -1.04, 0.21)
DEFAULT_STDS = (12.32, 11.47, 6.91, 0.86, 0.16)


@dataclass(frozen=True)
class InputSetup:
    """``residual``: current frame + ``n_past`` residual images; ``frames``: current + ``n_past`` past frames."""

    kind: str = "residual"
    n_past: int = 1

    def __post_init__(self) -> None:
        if self.kind not in ("residual", "frames"):
            raise ConfigError(f"input kind must be 'residual' or 'frames', got {self.kind!r}")
        if not 0 <= self.n_past <= 32:
            raise ConfigError(f"n_past must be in 0..32, got {self.n_past}")

    @property
    def channels(self) -> int:
        return 5 + self.n_past if self.kind == "residual" else 5 * (1 + self.n_past)

    @property
    def label(self) -> str:
        """Short name as in the paper's tables."""
        if self.n_past == 0:
            return "one frame"
        return f"residual N={self.n_past}" if self.kind == "residual" else f"{1 + self.n_past} frames"


def frame_channels(image: RangeImage, means: np.ndarray, stds: np.ndarray) -> np.ndarray:
    """(5, H, W) normalised r, x, y, z, e, zero where the image is empty (as LiDAR-MOS masks them)."""
    h, w = image.range.shape
    out = np.empty((5, h, w), dtype=np.float32)
    out[0] = image.range
    out[1:4] = np.moveaxis(image.xyz, -1, 0)
    out[4] = image.remission
    out -= np.asarray(means, np.float32)[:, None, None]
    out /= np.asarray(stds, np.float32)[:, None, None]
    out *= image.mask[None]
    return out


def assemble_input(
    current: RangeImage,
    extra: np.ndarray | list[RangeImage],
    setup: InputSetup,
    means: np.ndarray,
    stds: np.ndarray,
) -> np.ndarray:
    """(C, H, W) float32 network input for one scan.

    ``extra`` is the (n_past, H, W) residual stack for ``residual`` setups, or the past
    frames re-projected into the current frame (newest first) for ``frames`` setups;
    a missing past frame is all zeros, like a missing residual.
    """
    h, w = current.range.shape
    out = np.zeros((setup.channels, h, w), dtype=np.float32)
    out[:5] = frame_channels(current, means, stds)
    if setup.kind == "residual":
        res = np.asarray(extra, dtype=np.float32)
        if res.shape[1:] != (h, w) or len(res) > setup.n_past:
            raise ConfigError(f"residual stack of shape {res.shape} does not fit setup {setup} at {h} x {w}")
        out[5 : 5 + len(res)] = res
    else:
        frames = list(extra)[: setup.n_past]
        for j, frame in enumerate(frames):
            out[5 * (j + 1) : 5 * (j + 2)] = frame_channels(frame, means, stds)
    return out
