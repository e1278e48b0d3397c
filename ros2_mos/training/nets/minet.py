"""MINet (Li et al., RA-L 2021, "Multi-scale Interaction for Real-time LiDAR Data
Segmentation on an Embedded Platform"), re-implemented from the paper's description.

The ideas that matter for the MOS ablation are kept:

* a light, mobile-style network (depthwise-separable "mobile blocks", ~1 M parameters);
* a *multi-path* multi-scale module: three parallel paths at 1/2, 1/4 and 1/8 of the
  resolution, each fed by the average-pooled stem features, spending more operations
  on the low resolutions (2 / 4 / 6 blocks) where they are cheap;
* *interaction* between the paths half-way: every path receives the resized
  (bilinear / average pooled) and channel-projected features of the other two;
* a fusion of the three paths at 1/2 resolution, and an upsampling module that
  combines the upsampled features with a shallow full-resolution branch of the
  input (so thin structures and borders are recovered at full resolution).

The official code was not available here, so channel widths and block counts are
our choice and state dicts of the original do not load.  H and W must be divisible
by 8.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


class ConvBNReLU(nn.Sequential):
    def __init__(self, in_ch: int, out_ch: int, kernel: int = 3, stride: int = 1, groups: int = 1) -> None:
        super().__init__(
            nn.Conv2d(in_ch, out_ch, kernel, stride=stride, padding=kernel // 2, groups=groups, bias=False),
            nn.BatchNorm2d(out_ch),
            nn.ReLU6(inplace=True),
        )


class MobileBlock(nn.Module):
    """Depthwise 3x3 + pointwise 1x1 (MobileNet), residual when the shapes allow it."""

    def __init__(self, in_ch: int, out_ch: int) -> None:
        super().__init__()
        self.depthwise = ConvBNReLU(in_ch, in_ch, 3, groups=in_ch)
        self.pointwise = nn.Sequential(nn.Conv2d(in_ch, out_ch, 1, bias=False), nn.BatchNorm2d(out_ch))
        self.residual = in_ch == out_ch
        self.act = nn.ReLU6(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.pointwise(self.depthwise(x))
        return self.act(out + x if self.residual else out)


def _resize(x: torch.Tensor, size: torch.Size) -> torch.Tensor:
    if x.shape[-2:] == size:
        return x
    if x.shape[-1] > size[-1]:
        return F.adaptive_avg_pool2d(x, size)
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


class MultiScaleModule(nn.Module):
    """Three paths at 1/2, 1/4, 1/8 with an interaction step half-way, fused at 1/2."""

    def __init__(
        self, in_ch: int, widths: tuple[int, int, int] = (32, 64, 128), depths: tuple[int, int, int] = (2, 4, 6)
    ) -> None:
        super().__init__()
        self.entry = nn.ModuleList(ConvBNReLU(in_ch, w, 1) for w in widths)
        self.first = nn.ModuleList(
            nn.Sequential(*[MobileBlock(w, w) for _ in range(d // 2)]) for w, d in zip(widths, depths)
        )
        # interaction: for path i, a 1x1 projection of every other path j
        self.exchange = nn.ModuleList(
            nn.ModuleList(nn.Conv2d(widths[j], widths[i], 1, bias=False) if j != i else nn.Identity() for j in range(3))
            for i in range(3)
        )
        self.second = nn.ModuleList(
            nn.Sequential(*[MobileBlock(w, w) for _ in range(d - d // 2)]) for w, d in zip(widths, depths)
        )
        self.fuse = ConvBNReLU(sum(widths), widths[1], 1)
        self.out_channels = widths[1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        sizes = [torch.Size((h, w)), torch.Size((h // 2, w // 2)), torch.Size((h // 4, w // 4))]
        paths = [f(e(_resize(x, s))) for e, f, s in zip(self.entry, self.first, sizes)]
        mixed = []
        for i in range(3):
            acc = paths[i]
            for j in range(3):
                if j != i:
                    acc = acc + self.exchange[i][j](_resize(paths[j], sizes[i]))
            mixed.append(self.second[i](acc))
        return self.fuse(torch.cat([_resize(p, sizes[0]) for p in mixed], dim=1))


class MINet(nn.Module):
    """Stem (1/2) -> multi-scale module -> upsampling module with a full-resolution branch -> logits."""

    def __init__(self, in_channels: int = 5, n_classes: int = 2, stem: int = 32, full_res: int = 16) -> None:
        super().__init__()
        self.stem = nn.Sequential(ConvBNReLU(in_channels, stem, 3, stride=2), MobileBlock(stem, stem))
        self.multiscale = MultiScaleModule(stem)
        self.full = nn.Sequential(ConvBNReLU(in_channels, full_res, 3), ConvBNReLU(full_res, full_res, 3))
        self.up = ConvBNReLU(self.multiscale.out_channels, full_res, 1)
        self.refine = nn.Sequential(ConvBNReLU(2 * full_res, full_res, 3), nn.Dropout2d(0.1))
        self.head = nn.Conv2d(full_res, n_classes, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.multiscale(self.stem(x))
        y = F.interpolate(self.up(y), size=x.shape[-2:], mode="bilinear", align_corners=False)
        return self.head(self.refine(torch.cat([y, self.full(x)], dim=1)))
