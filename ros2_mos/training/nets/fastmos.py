"""FastMOS: a CPU real-time MOS network for 64 x 2048 range images.

Why this shape: on two CPU cores a SalsaNext-sized network costs several times the
whole node's 100 ms per 64 x 2048 scan in ONNX Runtime (benchmarks/design_figures.md).  Almost all of a
range-image CNN's cost is spent at full resolution, and a rotating LiDAR's image
is 32x wider than high, so this network

* patchifies the width by 4 in its first layer (a (3, 4) kernel with stride (1, 4)),
  so that the encoder runs on 64 x 512 and below, never on 64 x 2048;
* keeps few channels (16 / 32 / 48) and uses plain 3x3 convolutions, which ONNX
  Runtime's CPU kernels (MLAS, NCHW) run much better than depthwise ones at this size;
* gets context from dilations on the small maps instead of more depth;
* restores full resolution with a cheap *full-resolution refinement*: the
  decoder's 64 x 512 features are upsampled by 4 along the width and fused with a
  1x1 projection of the raw input at 64 x 2048, then a (1, 3) convolution and a 1x1
  classifier.  The residual images are sharp at full resolution, so that is where
  object borders are decided: pixels a strided encoder alone would blur.

The output is (B, n_classes, H, W) logits at the input's resolution; H must be
divisible by 4 and W by 16.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


class ConvBNAct(nn.Sequential):
    """Conv -> BatchNorm -> LeakyReLU, the unit every stage is built from (BN folds away in ONNX)."""

    def __init__(
        self,
        in_ch: int,
        out_ch: int,
        kernel: int | tuple[int, int] = 3,
        stride: int | tuple[int, int] = 1,
        dilation: int | tuple[int, int] = 1,
        padding: int | tuple[int, int] | None = None,
    ) -> None:
        k = (kernel, kernel) if isinstance(kernel, int) else kernel
        d = (dilation, dilation) if isinstance(dilation, int) else dilation
        if padding is None:
            padding = (d[0] * (k[0] - 1) // 2, d[1] * (k[1] - 1) // 2)
        super().__init__(
            nn.Conv2d(in_ch, out_ch, k, stride=stride, padding=padding, dilation=d, bias=False),
            nn.BatchNorm2d(out_ch),
            nn.LeakyReLU(0.1, inplace=True),
        )


class ResBlock(nn.Module):
    """Two 3x3 convolutions with a residual connection; the second one dilated for context."""

    def __init__(self, ch: int, dilation: int = 1) -> None:
        super().__init__()
        self.conv1 = ConvBNAct(ch, ch, 3)
        self.conv2 = nn.Sequential(
            nn.Conv2d(ch, ch, 3, padding=dilation, dilation=dilation, bias=False), nn.BatchNorm2d(ch)
        )
        self.act = nn.LeakyReLU(0.1, inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(x + self.conv2(self.conv1(x)))


class FastMOS(nn.Module):
    """The CPU real-time network (see the module docstring for the design)."""

    def __init__(
        self,
        in_channels: int,
        n_classes: int = 2,
        widths: tuple[int, int, int] = (16, 32, 48),
        full_res_channels: int = 8,
        width_stride: int = 4,
        dropout: float = 0.1,
    ) -> None:
        super().__init__()
        c1, c2, c3 = widths
        self.width_stride = width_stride
        # Stage 1 at H x W/4: a (3, ws) patchify conv keeps every input column in view.
        self.stem = ConvBNAct(in_channels, c1, (3, width_stride), stride=(1, width_stride), padding=(1, 0))
        self.enc1 = ResBlock(c1, dilation=1)
        # Stage 2 at H/2 x W/8.
        self.down2 = ConvBNAct(c1, c2, 3, stride=2)
        self.enc2 = nn.Sequential(ResBlock(c2, dilation=1), ResBlock(c2, dilation=2))
        # Stage 3 at H/4 x W/16: the context stage.
        self.down3 = ConvBNAct(c2, c3, 3, stride=2)
        self.enc3 = nn.Sequential(ResBlock(c3, dilation=2), ResBlock(c3, dilation=4))
        self.dropout = nn.Dropout2d(dropout)
        # Decoder: bilinear upsampling + skip fusion by 1x1 projection and a 3x3 conv.
        self.lat3 = ConvBNAct(c3, c2, 1)
        self.dec2 = ConvBNAct(c2, c2, 3)
        self.lat2 = ConvBNAct(c2, c1, 1)
        self.dec1 = ConvBNAct(c1, c1, 3)
        # Full-resolution refinement.
        self.full_in = ConvBNAct(in_channels, full_res_channels, 1)
        self.full_up = ConvBNAct(c1, full_res_channels, 1)
        self.refine = ConvBNAct(full_res_channels, full_res_channels, (1, 3))
        self.head = nn.Conv2d(full_res_channels, n_classes, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        e1 = self.enc1(self.stem(x))
        e2 = self.enc2(self.down2(e1))
        e3 = self.dropout(self.enc3(self.down3(e2)))
        d2 = self.dec2(e2 + F.interpolate(self.lat3(e3), size=e2.shape[-2:], mode="bilinear", align_corners=False))
        d1 = self.dec1(e1 + F.interpolate(self.lat2(d2), size=e1.shape[-2:], mode="bilinear", align_corners=False))
        up = F.interpolate(self.full_up(d1), size=x.shape[-2:], mode="bilinear", align_corners=False)
        return self.head(self.refine(self.full_in(x) + up))
