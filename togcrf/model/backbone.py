"""The backbone: a ResNet for 1-channel depth input with a feature pyramid (torchvision's ``BackboneWithFPN``).

The paper uses a ResNet-101 C4 map (Section IV-B); a feature pyramid is our choice, because the
objects of a pile span a wide range of sizes and it is torchvision's supported path. The ResNet is
randomly initialised and fully trainable (no pretrained depth weights exist to download).
"""

from __future__ import annotations

from collections.abc import Callable

from torch import nn
from torchvision.models import resnet
from torchvision.models.detection.backbone_utils import BackboneWithFPN
from torchvision.ops.feature_pyramid_network import LastLevelMaxPool

from togcrf.model.options import BackboneOptions

#: Supported ResNet depths (the paper uses resnet101), with the channels of their C2 (64 per basic block,
#: 256 per bottleneck; He et al. 2016, Table 1).
C2_CHANNELS = {"resnet18": 64, "resnet34": 64, "resnet50": 256, "resnet101": 256}
BACKBONES = tuple(C2_CHANNELS)

#: Strides of the ResNet stages C2-C5, pixels of the network input.
RESNET_STRIDES = (4, 8, 16, 32)


def norm_layer(kind: str) -> Callable[[int], nn.Module]:
    """A constructor ``channels -> normalisation module`` for ``kind`` in {"group", "batch"}."""
    if kind == "batch":
        return nn.BatchNorm2d
    if kind == "group":
        return lambda channels: nn.GroupNorm(min(32, channels), channels)
    raise ValueError(f"unknown normalisation {kind!r}; expected 'group' or 'batch'")


def kept_strides(options: BackboneOptions) -> tuple[int, ...]:
    """Strides of the ResNet stages the FPN takes, finest first: the FPN maps "0", "1", ... ("pool" excluded)."""
    return tuple(stride for stride in RESNET_STRIDES if options.fpn_min_stride <= stride <= options.fpn_max_stride)


def build_backbone(name: str, options: BackboneOptions) -> BackboneWithFPN:
    """A ResNet + FPN backbone for 1-channel depth input.

    Parameters
    ----------
    name : str
        One of ``BACKBONES``.
    options : BackboneOptions

    Returns
    -------
    BackboneWithFPN
        Maps "0", "1", ... at strides ``fpn_min_stride`` ... ``fpn_max_stride`` and "pool" at twice that.
    """
    if name not in BACKBONES:
        raise ValueError(f"unknown backbone {name!r}; expected one of {BACKBONES}")
    if options.fpn_min_stride not in RESNET_STRIDES[:2]:
        raise ValueError(f"backbone.fpn_min_stride {options.fpn_min_stride}: expected 4 or 8")
    if options.fpn_max_stride not in RESNET_STRIDES[2:]:
        raise ValueError(f"backbone.fpn_max_stride {options.fpn_max_stride}: expected 16 or 32")
    body = resnet.__dict__[name](weights=None, norm_layer=norm_layer(options.norm))
    body.conv1 = nn.Conv2d(1, body.conv1.out_channels, kernel_size=7, stride=2, padding=3, bias=False)
    nn.init.kaiming_normal_(body.conv1.weight, mode="fan_out", nonlinearity="relu")
    stages = [RESNET_STRIDES.index(stride) + 1 for stride in kept_strides(options)]
    returned = {f"layer{stage}": str(index) for index, stage in enumerate(stages)}
    return BackboneWithFPN(
        body, returned, [C2_CHANNELS[name] * 2 ** (stage - 1) for stage in stages], options.fpn_channels,
        extra_blocks=LastLevelMaxPool(), norm_layer=norm_layer(options.norm) if options.fpn_norm else None)
