"""The discriminator D: a PatchGAN (pix2pix ``NLayerDiscriminator``, 3 layers).

Layer table for ``num_layers=3`` and 64 base filters (pix2pix's defaults);
all kernels 4x4 with padding 1, LeakyReLU slope 0.2:

=====  ==================================  =======  ======
index  layers                              filters  stride
=====  ==================================  =======  ======
0      conv, LeakyReLU                     64       2
1      conv, norm, LeakyReLU               128      2
2      conv, norm, LeakyReLU               256      2
3      conv, norm, LeakyReLU               512      1
4      conv (patch logits)                 1        1
=====  ==================================  =======  ======

Each output pixel classifies one input patch as real or fake. Its receptive
field is ``1 + sum_i (k_i - 1) * prod_{j<i} s_j = 1 + 3 (1 + 2 + 4 + 8 + 8) =
70`` pixels: the classic 70x70 PatchGAN. :meth:`PatchDiscriminator.receptive_field`
computes it from the layers actually built.

The network is conditional as in pix2pix/pix2pixHD: the caller concatenates
the obstructed input and the (real or generated) clean image along channels,
so ``in_channels = 2 * C`` (see :func:`lenspair.model.networks.variants.build_discriminator`).
It returns every block's output, the last being the patch logits, so that
the generator can be trained with feature matching (pix2pixHD).

Normalisation is instance norm (pix2pixHD's choice) or ``"none"``. Instance
norm couples all positions of a map, so the receptive-field statement is
about the convolutional structure (exact with ``norm="none"``).
"""

from torch import Tensor, nn

from lenspair.model.errors import ModelError
from lenspair.model.networks.layers import make_norm

KERNEL_SIZE = 4
PADDING = 1


class PatchDiscriminator(nn.Module):
    """pix2pix ``NLayerDiscriminator`` returning intermediate features.

    Forward contract: ``(N, in_channels, H, W)`` float -> list of
    ``num_layers + 2`` feature maps; the last is ``(N, 1, H', W')`` raw patch
    logits (LSGAN: no sigmoid), ``H' ~ H / 2**num_layers - 2``.
    """

    def __init__(
        self,
        in_channels: int,
        num_filters: int = 64,
        num_layers: int = 3,
        norm: str = "instance",
    ) -> None:
        """Create the discriminator.

        Args:
            in_channels: input channels (``2 * C`` for the conditional use).
            num_filters: filters of the first layer; doubled per layer up to 8x.
            num_layers: number of stride-2 layers (3 for the 70x70 PatchGAN).
            norm: a key of :data:`lenspair.model.networks.layers.NORMS`.

        Raises:
            ModelError: on a non-positive channel/filter count or ``num_layers < 1``.
        """
        super().__init__()
        if in_channels < 1 or num_filters < 1 or num_layers < 1:
            raise ModelError(
                "in_channels, num_filters and num_layers must be positive, got "
                f"{in_channels}, {num_filters}, {num_layers}"
            )
        blocks: list[nn.Module] = [
            nn.Sequential(_conv(in_channels, num_filters, 2, bias=True), _leaky())
        ]
        filters = num_filters
        for index in range(1, num_layers + 1):
            previous = filters
            filters = num_filters * min(2**index, 8)
            stride = 2 if index < num_layers else 1
            norm_layer = make_norm(norm, filters)
            blocks.append(
                nn.Sequential(
                    _conv(previous, filters, stride, bias=isinstance(norm_layer, nn.Identity)),
                    norm_layer,
                    _leaky(),
                )
            )
        blocks.append(nn.Sequential(_conv(filters, 1, 1, bias=True)))
        self.blocks = nn.ModuleList(blocks)

    def forward(self, x: Tensor) -> list[Tensor]:
        """Classify the patches of ``x``.

        Args:
            x: ``(N, in_channels, H, W)`` float, typically ``cat(input, image)``
                in [0, 1]; ``H, W`` must be large enough for every 4x4 layer
                (at least 2 ** num_layers * 4 is safe).

        Returns:
            The output of every block, shallow to deep; ``[-1]`` is the patch
            logits ``(N, 1, H', W')``.
        """
        features = []
        for block in self.blocks:
            x = block(x)
            features.append(x)
        return features

    def receptive_field(self) -> int:
        """Side, in input pixels, of the patch that one output logit sees.

        Computed from the convolutions actually built:
        ``1 + sum_i (k_i - 1) * prod_{j<i} s_j``.

        Returns:
            The receptive field (70 for ``num_layers=3``).
        """
        field, jump = 1, 1
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                kernel = module.kernel_size[0]
                stride = module.stride[0]
                field += (kernel - 1) * jump
                jump *= stride
        return field


def min_input_side(num_layers: int = 3) -> int:
    """The smallest input side for which every 4x4 layer still has an output (24 for 3 layers).

    Each layer maps a side ``n`` to ``(n + 2 * PADDING - KERNEL_SIZE) // stride + 1``;
    ``num_layers`` of stride 2 are followed by two of stride 1 (the table above).
    Training crops must be at least this large.
    """
    strides = [2] * num_layers + [1, 1]
    side = 1
    while True:
        n = side
        for stride in strides:
            n = (n + 2 * PADDING - KERNEL_SIZE) // stride + 1 if n > 0 else 0
        if n >= 1:
            return side
        side += 1


def _conv(in_channels: int, out_channels: int, stride: int, bias: bool) -> nn.Conv2d:
    return nn.Conv2d(
        in_channels, out_channels, KERNEL_SIZE, stride=stride, padding=PADDING, bias=bias
    )


def _leaky() -> nn.LeakyReLU:
    return nn.LeakyReLU(0.2, inplace=True)
