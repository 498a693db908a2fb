"""A small encoder-decoder segmentation network, trained from scratch.

Four encoder stages (stride 2 each, two 3x3 conv + batch norm + ReLU per
stage) and a U-Net style decoder that upsamples, concatenates the matching
encoder stage and mixes with one 3x3 conv; a 1x1 head predicts the classes
at half resolution and bilinear upsampling brings them to the input size.
With the default widths it has about 0.5M parameters. Input sides that are
multiples of 16 halve exactly at every stage (160x96, idda shifts); others
work too, each decoder stage resizing to its skip (160x120, --camvid).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

WIDTHS = (24, 40, 80, 112)  # channels of the four encoder stages
DECODER_HEAD = 32  # channels of the last decoder stage
STRIDE = 2 ** len(WIDTHS)  # total downsampling: input sides must be multiples of this


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class SegNet(nn.Module):
    def __init__(self, num_classes: int, widths: tuple[int, ...] = WIDTHS, head: int = DECODER_HEAD) -> None:
        super().__init__()
        chans = (3,) + tuple(widths)
        self.encoder = nn.ModuleList(
            nn.Sequential(_conv(chans[i], chans[i + 1], stride=2), _conv(chans[i + 1], chans[i + 1]))
            for i in range(len(widths))
        )
        # Decoder stage k joins the upsampled deeper features with encoder stage k.
        outs = list(widths[1:-1][::-1]) + [head]  # e.g. 80, 40, 32
        self.decoder = nn.ModuleList()
        deeper = widths[-1]
        for skip, out in zip(widths[-2::-1], outs):
            self.decoder.append(_conv(deeper + skip, out))
            deeper = out
        self.classifier = nn.Conv2d(deeper, num_classes, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = x.shape[-2:]
        skips = []
        for stage in self.encoder:
            x = stage(x)
            skips.append(x)
        x = skips.pop()
        for stage in self.decoder:
            skip = skips.pop()
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = stage(torch.cat([x, skip], dim=1))
        return F.interpolate(self.classifier(x), size=size, mode="bilinear", align_corners=False)


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
