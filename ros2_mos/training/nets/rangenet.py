"""RangeNet++ (Milioto et al., 2019): the Darknet encoder-decoder on range images.

As published: a 3x3 stem, five encoder stages that each downsample the *width*
only by 2 (stride [1, 2]) followed by Darknet residual blocks (1x1 then 3x3), a
decoder of transposed convolutions ([1, 4] kernel, stride [1, 2]) each followed by
one residual block, skip additions at every scale, Dropout2d(0.01) and a 3x3
classification head.  Darknet-21 has [1, 1, 2, 2, 1] blocks per stage, Darknet-53
[1, 2, 8, 8, 4].  Parameter names follow the original (``backbone.conv1``,
``backbone.enc1.conv``, ``backbone.enc1.residual_0.conv1``, ``decoder.dec5.upconv``,
``head.1``).  As in the original, the skip connections are detached (no gradient
flows through them); ``detach_skips=False`` lets them train.  The output is logits
at the input resolution; the width must be divisible by 32.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
from torch import nn

MODEL_BLOCKS = {21: [1, 1, 2, 2, 1], 53: [1, 2, 8, 8, 4]}


class BasicBlock(nn.Module):
    """Darknet residual block: 1x1 bottleneck to planes[0], 3x3 back to planes[1], plus the input."""

    def __init__(self, inplanes: int, planes: list[int], bn_d: float = 0.1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes[0], kernel_size=1, stride=1, padding=0, bias=False)
        self.bn1 = nn.BatchNorm2d(planes[0], momentum=bn_d)
        self.relu1 = nn.LeakyReLU(0.1)
        self.conv2 = nn.Conv2d(planes[0], planes[1], kernel_size=3, stride=1, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes[1], momentum=bn_d)
        self.relu2 = nn.LeakyReLU(0.1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu1(self.bn1(self.conv1(x)))
        out = self.relu2(self.bn2(self.conv2(out)))
        return out + x


class Backbone(nn.Module):
    """Darknet encoder; returns the deepest features and the skips keyed by width stride."""

    def __init__(self, in_channels: int, layers: int = 21, bn_d: float = 0.1, drop_prob: float = 0.01) -> None:
        super().__init__()
        if layers not in MODEL_BLOCKS:
            raise ValueError(f"Darknet depth must be one of {sorted(MODEL_BLOCKS)}, got {layers}")
        blocks = MODEL_BLOCKS[layers]
        self.input_depth = in_channels
        self.conv1 = nn.Conv2d(in_channels, 32, kernel_size=3, stride=1, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(32, momentum=bn_d)
        self.relu1 = nn.LeakyReLU(0.1)
        self.enc1 = self._make_enc_layer([32, 64], blocks[0], 2, bn_d)
        self.enc2 = self._make_enc_layer([64, 128], blocks[1], 2, bn_d)
        self.enc3 = self._make_enc_layer([128, 256], blocks[2], 2, bn_d)
        self.enc4 = self._make_enc_layer([256, 512], blocks[3], 2, bn_d)
        self.enc5 = self._make_enc_layer([512, 1024], blocks[4], 2, bn_d)
        self.dropout = nn.Dropout2d(drop_prob)
        self.last_channels = 1024

    @staticmethod
    def _make_enc_layer(planes: list[int], blocks: int, stride: int, bn_d: float) -> nn.Sequential:
        layers: list[tuple[str, nn.Module]] = [
            (
                "conv",
                nn.Conv2d(planes[0], planes[1], kernel_size=3, stride=[1, stride], dilation=1, padding=1, bias=False),
            ),
            ("bn", nn.BatchNorm2d(planes[1], momentum=bn_d)),
            ("relu", nn.LeakyReLU(0.1)),
        ]
        for i in range(blocks):
            layers.append((f"residual_{i}", BasicBlock(planes[1], planes, bn_d)))
        return nn.Sequential(OrderedDict(layers))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        x = self.relu1(self.bn1(self.conv1(x)))
        skips = [x]  # width strides 1, 2, 4, 8, 16 (the 32 one is the output)
        for stage in (self.enc1, self.enc2, self.enc3, self.enc4):
            x = self.dropout(stage(x))
            skips.append(x)
        x = self.dropout(self.enc5(x))
        return x, skips


class Decoder(nn.Module):
    """Darknet decoder: transposed convs doubling the width, each + a residual block + the skip."""

    def __init__(self, bn_d: float = 0.1, drop_prob: float = 0.01, detach_skips: bool = True) -> None:
        super().__init__()
        self.detach_skips = detach_skips
        self.dec5 = self._make_dec_layer([1024, 512], bn_d)
        self.dec4 = self._make_dec_layer([512, 256], bn_d)
        self.dec3 = self._make_dec_layer([256, 128], bn_d)
        self.dec2 = self._make_dec_layer([128, 64], bn_d)
        self.dec1 = self._make_dec_layer([64, 32], bn_d)
        self.dropout = nn.Dropout2d(drop_prob)
        self.last_channels = 32

    @staticmethod
    def _make_dec_layer(planes: list[int], bn_d: float) -> nn.Sequential:
        return nn.Sequential(
            OrderedDict(
                [
                    (
                        "upconv",
                        nn.ConvTranspose2d(planes[0], planes[1], kernel_size=[1, 4], stride=[1, 2], padding=[0, 1]),
                    ),
                    ("bn", nn.BatchNorm2d(planes[1], momentum=bn_d)),
                    ("relu", nn.LeakyReLU(0.1)),
                    ("residual", BasicBlock(planes[1], planes, bn_d)),
                ]
            )
        )

    def forward(self, x: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        for layer, skip in zip((self.dec5, self.dec4, self.dec3, self.dec2, self.dec1), reversed(skips)):
            x = layer(x) + (skip.detach() if self.detach_skips else skip)
        return self.dropout(x)


class RangeNet(nn.Module):
    """Backbone + decoder + head (RangeNet++'s ``Segmentator``) returning logits."""

    def __init__(self, in_channels: int = 5, n_classes: int = 2, layers: int = 21, detach_skips: bool = True) -> None:
        super().__init__()
        self.backbone = Backbone(in_channels, layers)
        self.decoder = Decoder(detach_skips=detach_skips)
        self.head = nn.Sequential(nn.Dropout2d(p=0.01), nn.Conv2d(32, n_classes, kernel_size=3, stride=1, padding=1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features, skips = self.backbone(x)
        return self.head(self.decoder(features, skips))


class RangeNet21(RangeNet):
    """RangeNet++ with the Darknet-21 backbone (the variant LiDAR-MOS evaluates)."""

    def __init__(self, in_channels: int = 5, n_classes: int = 2, detach_skips: bool = True) -> None:
        super().__init__(in_channels, n_classes, 21, detach_skips)


class RangeNet53(RangeNet):
    """RangeNet++ with the Darknet-53 backbone."""

    def __init__(self, in_channels: int = 5, n_classes: int = 2, detach_skips: bool = True) -> None:
        super().__init__(in_channels, n_classes, 53, detach_skips)
