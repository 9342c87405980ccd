"""DeRaindrop's generator, re-implemented layer for layer, for timing only.

Qian et al., "Attentive Generative Adversarial Network for Raindrop Removal
from a Single Image" (CVPR 2018). Written from the published architecture
(the paper's Sec. 4 and its released generator): an attentive-recurrent
network of 4 time steps, each a 3x3 conv (4 -> 32) + 5 residual blocks (two
3x3 convs of 32) + a convolutional LSTM (32 + 32 -> 32, 3x3 gates) + a 3x3
conv to a one-channel attention map; then a contextual autoencoder on
``cat(image, attention)``: 16 conv + ReLU blocks with two stride-2 stages,
four dilated 3x3 convs (2, 4, 8, 16), two transposed convs back up (each
reflection-padded and 2x2 average-pooled, as released) with skip additions,
and the multi-scale side outputs at 1/4 and 1/2. 6.24 M parameters. Its
weights are random: it is timed, never evaluated. Input ``(N, 3, H, W)``
float32, ``H, W`` multiples of 4.
"""

import torch
from torch import Tensor, nn

ITERATIONS = 4


def _conv(cin: int, cout: int, kernel: int = 3, stride: int = 1, dilation: int = 1) -> nn.Module:
    padding = dilation * (kernel // 2)
    return nn.Sequential(nn.Conv2d(cin, cout, kernel, stride, padding, dilation), nn.ReLU())


def _up(cin: int, cout: int) -> nn.Module:
    return nn.Sequential(
        nn.ConvTranspose2d(cin, cout, 4, 2, 1),
        nn.ReflectionPad2d((1, 0, 1, 0)),
        nn.AvgPool2d(2, stride=1),
        nn.ReLU(),
    )


class DeRaindropGenerator(nn.Module):
    """The attentive-recurrent network + contextual autoencoder (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        self.det_conv0 = _conv(4, 32)
        self.det_blocks = nn.ModuleList(
            nn.Sequential(_conv(32, 32), _conv(32, 32)) for _ in range(5)
        )
        self.gate_i = nn.Sequential(nn.Conv2d(64, 32, 3, 1, 1), nn.Sigmoid())
        self.gate_f = nn.Sequential(nn.Conv2d(64, 32, 3, 1, 1), nn.Sigmoid())
        self.gate_g = nn.Sequential(nn.Conv2d(64, 32, 3, 1, 1), nn.Tanh())
        self.gate_o = nn.Sequential(nn.Conv2d(64, 32, 3, 1, 1), nn.Sigmoid())
        self.det_conv_mask = nn.Conv2d(32, 1, 3, 1, 1)
        self.conv1 = _conv(4, 64, 5)
        self.conv2 = _conv(64, 128, 3, 2)
        self.conv3 = _conv(128, 128)
        self.conv4 = _conv(128, 256, 3, 2)
        self.conv5 = _conv(256, 256)
        self.conv6 = _conv(256, 256)
        self.dilated = nn.Sequential(*(_conv(256, 256, dilation=d) for d in (2, 4, 8, 16)))
        self.conv7 = _conv(256, 256)
        self.conv8 = _conv(256, 256)
        self.deconv1 = _up(256, 128)
        self.conv9 = _conv(128, 128)
        self.deconv2 = _up(128, 64)
        self.conv10 = _conv(64, 32)
        self.outframe1 = _conv(256, 3)
        self.outframe2 = _conv(128, 3)
        self.output = nn.Conv2d(32, 3, 3, 1, 1)

    def forward(self, image: Tensor) -> tuple[list[Tensor], Tensor, Tensor, Tensor]:
        """``(N, 3, H, W)`` -> (attention maps, 1/4 frame, 1/2 frame, restored)."""
        batch, _, height, width = image.shape
        mask = torch.full((batch, 1, height, width), 0.5, dtype=image.dtype, device=image.device)
        hidden = torch.zeros(batch, 32, height, width, dtype=image.dtype, device=image.device)
        cell = torch.zeros_like(hidden)
        masks = []
        for _ in range(ITERATIONS):
            x = self.det_conv0(torch.cat([image, mask], 1))
            for block in self.det_blocks:
                x = torch.relu(block(x) + x)
            x = torch.cat([x, hidden], 1)
            cell = self.gate_f(x) * cell + self.gate_i(x) * self.gate_g(x)
            hidden = self.gate_o(x) * torch.tanh(cell)
            mask = self.det_conv_mask(hidden)
            masks.append(mask)
        x = self.conv1(torch.cat([image, mask], 1))
        skip1 = x
        x = self.conv2(x)
        skip2 = x
        x = self.conv8(self.conv7(self.dilated(self.conv6(self.conv5(self.conv4(self.conv3(x)))))))
        frame1 = self.outframe1(x)
        x = self.conv9(self.deconv1(x) + skip2)
        frame2 = self.outframe2(x)
        x = self.conv10(self.deconv2(x) + skip1)
        return masks, frame1, frame2, self.output(x)
