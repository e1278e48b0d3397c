"""The network input: which channels a model takes and how they are assembled.

The paper's ablation feeds the CNN either frames (5 channels each: r, x, y, z, e)
or the current frame plus N residual images (5 + N channels).  The setup and the
normalisation travel with the model (see :mod:`ros2_mos.core.metadata`), so the
pipeline builds exactly what the network was trained on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ros2_mos.core.errors import ConfigError
from ros2_mos.core.projection import RangeImage

# LiDAR-MOS / SalsaNext's SemanticKITTI statistics for (r, x, y, z, e).
DEFAULT_MEANS = (12.12, 10.88, 0.23, -1.04, 0.21)
DEFAULT_STDS = (12.32, 11.47, 6.91, 0.86, 0.16)


#: The per-pixel channels of a projected scan, in the order of the model's means/stds.
IMAGE_CHANNELS = ("range", "x", "y", "z", "remission")


@dataclass(frozen=True)
class InputSetup:
    """What the network sees: the current scan's image channels plus the past.

    ``kind`` ``residual``: ``n_past`` residual images against the scans ``past_offsets``
    back (default 1..n_past, newest first), as ``|r_0 - r_j| / r_0`` or, with ``signed``,
    ``(r_j - r_0) / r_0``: positive where the past ray passed farther (the space the current
    point occupies was free: something moved in), negative where something stood closer
    (it moved away, or the current point was hidden behind it).  ``frames``: the current
    frame plus ``n_past`` past frames re-projected into it.

    ``free_space`` (residual inputs) adds ``n_past`` free-space images at the same offsets
    (:func:`ros2_mos.core.residuals.free_space_image`): the residual asked along the past scan's own
    rays, which tells a point that stood where a past ray passed through (it moved in) from a
    surface that the past scan saw from another side.

    ``image_channels`` picks which of r, x, y, z, remission of each frame the network
    takes (LiDAR-MOS takes all five; a model without remission does not depend on a
    driver's intensity scale).
    """

    kind: str = "residual"
    n_past: int = 1
    past_offsets: tuple[int, ...] = ()
    signed: bool = False
    image_channels: tuple[str, ...] = IMAGE_CHANNELS
    free_space: bool = False

    def __post_init__(self) -> None:
        # JSON metadata brings lists back: keep the dataclass hashable and comparable.
        object.__setattr__(self, "past_offsets", tuple(int(o) for o in self.past_offsets))
        object.__setattr__(self, "image_channels", tuple(str(c) for c in self.image_channels))
        if self.kind not in ("residual", "frames"):
            raise ConfigError(f"input kind must be 'residual' or 'frames', got {self.kind!r}")
        if not 0 <= self.n_past <= 32:
            raise ConfigError(f"n_past must be in 0..32, got {self.n_past}")
        if self.past_offsets:
            if self.kind != "residual":
                raise ConfigError("past_offsets apply to residual inputs only")
            if len(self.past_offsets) != self.n_past:
                raise ConfigError(f"past_offsets {list(self.past_offsets)} must list n_past={self.n_past} offsets")
            if self.past_offsets[0] < 1 or any(b <= a for a, b in zip(self.past_offsets, self.past_offsets[1:])):
                raise ConfigError(f"past_offsets must be increasing integers >= 1, got {list(self.past_offsets)}")
            if self.past_offsets[-1] > 32:
                raise ConfigError(f"past_offsets reach at most 32 scans back, got {self.past_offsets[-1]}")
        if self.signed and self.kind != "residual":
            raise ConfigError("signed applies to residual inputs only")
        if self.free_space and (self.kind != "residual" or self.n_past == 0):
            raise ConfigError("free_space applies to residual inputs with n_past >= 1 only")
        unknown = [c for c in self.image_channels if c not in IMAGE_CHANNELS]
        if unknown or not self.image_channels or len(set(self.image_channels)) != len(self.image_channels):
            raise ConfigError(f"image_channels must be distinct names out of {list(IMAGE_CHANNELS)}, "
                              f"got {list(self.image_channels)}")
        if self.kind == "frames" and self.image_channels != IMAGE_CHANNELS:
            raise ConfigError("frames inputs take all five image channels")

    @property
    def offsets(self) -> tuple[int, ...]:
        """How many scans back each past input is (1 = the previous scan)."""
        return self.past_offsets or tuple(range(1, self.n_past + 1))

    @property
    def history(self) -> int:
        """How many past scans must be kept to build the input."""
        return max(self.offsets, default=0)

    @property
    def channel_index(self) -> tuple[int, ...]:
        """Indices of the used image channels in r, x, y, z, remission."""
        return tuple(IMAGE_CHANNELS.index(c) for c in self.image_channels)

    @property
    def uses_remission(self) -> bool:
        return "remission" in self.image_channels

    @property
    def past_channels(self) -> int:
        """Channels built from the past scans: residuals (then free-space images), or past frames."""
        if self.kind == "residual":
            return self.n_past * (2 if self.free_space else 1)
        return len(self.image_channels) * self.n_past

    @property
    def channels(self) -> int:
        return len(self.image_channels) + self.past_channels

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Each input channel in :func:`assemble_input`'s order: the image channels, then ``residual@K`` (and
        ``free_space@K``) for K scans back, or ``C@K`` for channel C of the frame K scans back."""
        if self.kind == "residual":
            past = [f"residual@{o}" for o in self.offsets]
            past += [f"free_space@{o}" for o in self.offsets] if self.free_space else []
        else:
            past = [f"{c}@{k}" for k in range(1, self.n_past + 1) for c in self.image_channels]
        return (*self.image_channels, *past)

    @property
    def label(self) -> str:
        """Short name as in the paper's tables."""
        if self.n_past == 0:
            return "one frame"
        if self.kind == "frames":
            return f"{1 + self.n_past} frames"
        text = f"{'signed ' if self.signed else ''}residual N={self.n_past}"
        text += f" at {','.join(map(str, self.offsets))}" if self.past_offsets else ""
        return text + (" + free space" if self.free_space else "")


def frame_channels(
    image: RangeImage, means: np.ndarray, stds: np.ndarray, index: tuple[int, ...] = (0, 1, 2, 3, 4)
) -> np.ndarray:
    """(len(index), H, W) normalised channels out of r, x, y, z, e, zero where the image is empty.

    LiDAR-MOS masks its inputs the same way.
    """
    h, w = image.range.shape
    sources = (image.range, image.xyz[..., 0], image.xyz[..., 1], image.xyz[..., 2], image.remission)
    means = np.asarray(means, np.float32)
    stds = np.asarray(stds, np.float32)
    out = np.empty((len(index), h, w), dtype=np.float32)
    for k, c in enumerate(index):
        np.subtract(sources[c], means[c], out=out[k])
        out[k] /= stds[c]
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

    ``extra`` is the (n_past, H, W) residual stack for ``residual`` setups (signed
    residuals when ``setup.signed``, else absolute ones; an absolute value is taken here
    if signed ones are given to an unsigned setup), followed by the n_past free-space images
    when ``setup.free_space``; or the past frames re-projected into the current frame (newest
    first) for ``frames`` setups. A missing past input is all zeros.
    """
    h, w = current.range.shape
    out = np.zeros((setup.channels, h, w), dtype=np.float32)
    n_frame = len(setup.image_channels)
    out[:n_frame] = frame_channels(current, means, stds, setup.channel_index)
    if setup.kind == "residual":
        res = np.asarray(extra, dtype=np.float32)
        if res.ndim != 3 or res.shape[1:] != (h, w) or len(res) > setup.past_channels or (
                setup.free_space and len(res) != setup.past_channels):
            raise ConfigError(f"residual stack of shape {res.shape} does not fit setup {setup} at {h} x {w}")
        out[n_frame : n_frame + len(res)] = res
        if not setup.signed:
            n_abs = min(len(res), setup.n_past)  # free-space images keep their sign
            np.abs(out[n_frame : n_frame + n_abs], out=out[n_frame : n_frame + n_abs])
    else:
        frames = list(extra)[: setup.n_past]
        for j, frame in enumerate(frames):
            out[5 * (j + 1) : 5 * (j + 2)] = frame_channels(frame, means, stds)
    return out
