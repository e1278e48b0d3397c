"""SalsaNext (Cortinhal et al., 2020) as used by LiDAR-MOS, for any number of input channels.

The blocks and parameter names follow the published implementation
(``downCntx*``, ``resBlock1..5``, ``upBlock1..4``, ``logits``; inside the blocks
``conv1..5``/``bn1..4``), so a state dict of the same architecture loads with
``load_state_dict``.  One deliberate difference: ``forward`` returns logits, not
the softmax, because the losses here take logits and the exporter appends the
softmax to the ONNX graph (LiDAR-MOS's model applies it inside the network).

Input height must be divisible by 16 and width by 16 (four 2x average pools).
"""

from __future__ import annotations

import torch
from torch import nn


class ResContextBlock(nn.Module):
    """1x1 shortcut, then 3x3 and dilated 3x3 convolutions: early context at full resolution."""

    def __init__(self, in_filters: int, out_filters: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_filters, out_filters, kernel_size=(1, 1), stride=1)
        self.act1 = nn.LeakyReLU()
        self.conv2 = nn.Conv2d(out_filters, out_filters, (3, 3), padding=1)
        self.act2 = nn.LeakyReLU()
        self.bn1 = nn.BatchNorm2d(out_filters)
        self.conv3 = nn.Conv2d(out_filters, out_filters, (3, 3), dilation=2, padding=2)
        self.act3 = nn.LeakyReLU()
        self.bn2 = nn.BatchNorm2d(out_filters)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        shortcut = self.act1(self.conv1(x))
        res_a1 = self.bn1(self.act2(self.conv2(shortcut)))
        res_a2 = self.bn2(self.act3(self.conv3(res_a1)))
        return shortcut + res_a2


class ResBlock(nn.Module):
    """Residual block of 3x3, dilated 3x3 and dilated 2x2 convs concatenated, then dropout + avg pool."""

    def __init__(
        self,
        in_filters: int,
        out_filters: int,
        dropout_rate: float,
        kernel_size: tuple[int, int] = (3, 3),
        stride: int = 1,
        pooling: bool = True,
        drop_out: bool = True,
    ) -> None:
        super().__init__()
        self.pooling = pooling
        self.drop_out = drop_out
        self.conv1 = nn.Conv2d(in_filters, out_filters, kernel_size=(1, 1), stride=stride)
        self.act1 = nn.LeakyReLU()
        self.conv2 = nn.Conv2d(in_filters, out_filters, kernel_size=(3, 3), padding=1)
        self.act2 = nn.LeakyReLU()
        self.bn1 = nn.BatchNorm2d(out_filters)
        self.conv3 = nn.Conv2d(out_filters, out_filters, kernel_size=(3, 3), dilation=2, padding=2)
        self.act3 = nn.LeakyReLU()
        self.bn2 = nn.BatchNorm2d(out_filters)
        self.conv4 = nn.Conv2d(out_filters, out_filters, kernel_size=(2, 2), dilation=2, padding=1)
        self.act4 = nn.LeakyReLU()
        self.bn3 = nn.BatchNorm2d(out_filters)
        self.conv5 = nn.Conv2d(out_filters * 3, out_filters, kernel_size=(1, 1))
        self.act5 = nn.LeakyReLU()
        self.bn4 = nn.BatchNorm2d(out_filters)
        self.dropout = nn.Dropout2d(p=dropout_rate)
        if pooling:
            self.pool = nn.AvgPool2d(kernel_size=kernel_size, stride=2, padding=1)

    def forward(self, x: torch.Tensor):
        shortcut = self.act1(self.conv1(x))
        res_a1 = self.bn1(self.act2(self.conv2(x)))
        res_a2 = self.bn2(self.act3(self.conv3(res_a1)))
        res_a3 = self.bn3(self.act4(self.conv4(res_a2)))
        res_a = self.bn4(self.act5(self.conv5(torch.cat((res_a1, res_a2, res_a3), dim=1))))
        res_a = shortcut + res_a
        res_b = self.dropout(res_a) if self.drop_out else res_a
        if self.pooling:
            return self.pool(res_b), res_a
        return res_b


class UpBlock(nn.Module):
    """Pixel-shuffle upsampling, skip concatenation, then the same three-conv residual pattern."""

    def __init__(self, in_filters: int, out_filters: int, dropout_rate: float, drop_out: bool = True) -> None:
        super().__init__()
        self.drop_out = drop_out
        self.in_filters = in_filters
        self.out_filters = out_filters
        self.dropout1 = nn.Dropout2d(p=dropout_rate)
        self.dropout2 = nn.Dropout2d(p=dropout_rate)
        self.conv1 = nn.Conv2d(in_filters // 4 + 2 * out_filters, out_filters, (3, 3), padding=1)
        self.act1 = nn.LeakyReLU()
        self.bn1 = nn.BatchNorm2d(out_filters)
        self.conv2 = nn.Conv2d(out_filters, out_filters, (3, 3), dilation=2, padding=2)
        self.act2 = nn.LeakyReLU()
        self.bn2 = nn.BatchNorm2d(out_filters)
        self.conv3 = nn.Conv2d(out_filters, out_filters, (2, 2), dilation=2, padding=1)
        self.act3 = nn.LeakyReLU()
        self.bn3 = nn.BatchNorm2d(out_filters)
        self.conv4 = nn.Conv2d(out_filters * 3, out_filters, kernel_size=(1, 1))
        self.act4 = nn.LeakyReLU()
        self.bn4 = nn.BatchNorm2d(out_filters)
        self.dropout3 = nn.Dropout2d(p=dropout_rate)
        self.shuffle = nn.PixelShuffle(2)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        up_a = self.shuffle(x)
        if self.drop_out:
            up_a = self.dropout1(up_a)
        up_b = torch.cat((up_a, skip), dim=1)
        if self.drop_out:
            up_b = self.dropout2(up_b)
        up_e1 = self.bn1(self.act1(self.conv1(up_b)))
        up_e2 = self.bn2(self.act2(self.conv2(up_e1)))
        up_e3 = self.bn3(self.act3(self.conv3(up_e2)))
        up_e = self.bn4(self.act4(self.conv4(torch.cat((up_e1, up_e2, up_e3), dim=1))))
        if self.drop_out:
            up_e = self.dropout3(up_e)
        return up_e


class SalsaNext(nn.Module):
    """SalsaNext with ``in_channels`` inputs (5 + N for residual setups) and ``n_classes`` logits."""

    def __init__(self, in_channels: int = 5, n_classes: int = 2, base: int = 32, dropout: float = 0.2) -> None:
        super().__init__()
        self.nclasses = n_classes
        b = base
        self.downCntx = ResContextBlock(in_channels, b)
        self.downCntx2 = ResContextBlock(b, b)
        self.downCntx3 = ResContextBlock(b, b)
        self.resBlock1 = ResBlock(b, 2 * b, dropout, pooling=True, drop_out=False)
        self.resBlock2 = ResBlock(2 * b, 2 * 2 * b, dropout, pooling=True)
        self.resBlock3 = ResBlock(2 * 2 * b, 2 * 4 * b, dropout, pooling=True)
        self.resBlock4 = ResBlock(2 * 4 * b, 2 * 4 * b, dropout, pooling=True)
        self.resBlock5 = ResBlock(2 * 4 * b, 2 * 4 * b, dropout, pooling=False)
        self.upBlock1 = UpBlock(2 * 4 * b, 4 * b, dropout)
        self.upBlock2 = UpBlock(4 * b, 4 * b, dropout)
        self.upBlock3 = UpBlock(4 * b, 2 * b, dropout)
        self.upBlock4 = UpBlock(2 * b, b, dropout, drop_out=False)
        self.logits = nn.Conv2d(b, n_classes, kernel_size=(1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        down_cntx = self.downCntx3(self.downCntx2(self.downCntx(x)))
        down0c, down0b = self.resBlock1(down_cntx)
        down1c, down1b = self.resBlock2(down0c)
        down2c, down2b = self.resBlock3(down1c)
        down3c, down3b = self.resBlock4(down2c)
        down5c = self.resBlock5(down3c)
        up4e = self.upBlock1(down5c, down3b)
        up3e = self.upBlock2(up4e, down2b)
        up2e = self.upBlock3(up3e, down1b)
        up1e = self.upBlock4(up2e, down0b)
        return self.logits(up1e)
