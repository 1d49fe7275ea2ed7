"""RoIAlign whose backward pass on the CPU is one sparse matrix product.

torchvision's RoIAlign (Mask R-CNN's bilinear pooling, He et al. 2017) has a
fast CPU forward: it computes each RoI's bilinear sampling weights once and
reuses them for every channel. Its CPU backward does not: it recomputes the
weights for every channel and scatters into the ``(N, C, H, W)`` gradient one
element at a time, on one thread: in a CPU training step of a small
detector it costs several times the forward pass.

The pooling is linear in the features: with the feature map as a
``(N * H * W, C)`` matrix ``F`` (one row per pixel) and the output as a
``(R * PH * PW, C)`` matrix (one row per output cell), ``output = M @ F`` for
a sparse ``M`` that holds, for each cell, the 4 bilinear corner weights of
each of its ``S x S`` sampling points divided by ``S * S``. The gradient of
the features is then ``M^T @ grad_output``: here ``M^T`` is built once per
backward pass (the weights, vectorised over every sampling point, then one
sort by pixel) and multiplied in one sparse-dense product, shared by all
channels.

The forward stays torchvision's, so a model's outputs are exactly what they
were; only the gradient's floating-point summation order differs (the tests
compare it with torchvision's backward). CUDA tensors, the adaptive sampling
grid (``sampling_ratio <= 0``) and inference (no gradient) go to
torchvision unchanged.
"""

from __future__ import annotations

import warnings

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable
from torchvision.ops import MultiScaleRoIAlign, roi_align
from torchvision.ops._utils import convert_boxes_to_roi_format  # what torchvision's own poolers call

#: Bilinear corners per sampling point.
CORNERS = 4


def bilinear_weights(
    rois: Tensor, height: int, width: int, output_size: tuple[int, int], spatial_scale: float, sampling_ratio: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """The entries of RoIAlign's sparse matrix ``M``: which pixel feeds which output cell, with what weight.

    Follows torchvision's CPU kernel (``roi_align_kernel.cpp``, ``aligned=False``):
    a RoI spans at least one feature pixel; the ``S x S`` points of a bin sit at
    ``start + p * bin + (i + 0.5) * bin / S``; a point further than one pixel
    outside the map contributes nothing, one just outside is clamped to the
    border.

    Parameters
    ----------
    rois : (R, 5) float
        ``(batch_index, x1, y1, x2, y2)`` in input pixels.
    height, width : int
        Size of the feature map.
    output_size : (PH, PW)
    spatial_scale : float
        Feature pixels per input pixel.
    sampling_ratio : int
        ``S``, sampling points per bin along each side (> 0).

    Returns
    -------
    pixels : (R * PH * PW * S * S * 4,) int64
        Flat index ``batch * H * W + y * W + x`` of the feature pixel.
    cells : same shape, int64
        Flat index ``roi * PH * PW + ph * PW + pw`` of the output cell.
    weights : same shape, float (the dtype of ``rois``)
        Bilinear weight divided by ``S * S``; 0 for a point outside the map.
    """
    pooled_height, pooled_width = output_size
    samples = sampling_ratio
    batch = rois[:, 0].long()
    start_x, start_y, end_x, end_y = (rois[:, column] * spatial_scale for column in range(1, 5))
    bin_height = (end_y - start_y).clamp(min=1.0) / pooled_height
    bin_width = (end_x - start_x).clamp(min=1.0) / pooled_width
    offsets = torch.arange(samples, dtype=rois.dtype, device=rois.device) + 0.5
    bins_y = torch.arange(pooled_height, dtype=rois.dtype, device=rois.device)
    bins_x = torch.arange(pooled_width, dtype=rois.dtype, device=rois.device)
    # (R, PH, S) and (R, PW, S), in the kernel's order of operations.
    y = (start_y[:, None, None] + bins_y[None, :, None] * bin_height[:, None, None]
         + offsets[None, None, :] * bin_height[:, None, None] / samples)
    x = (start_x[:, None, None] + bins_x[None, :, None] * bin_width[:, None, None]
         + offsets[None, None, :] * bin_width[:, None, None] / samples)
    shape = (len(rois), pooled_height, pooled_width, samples, samples)
    y = y[:, :, None, :, None].expand(shape)
    x = x[:, None, :, None, :].expand(shape)
    inside = (y >= -1.0) & (y <= height) & (x >= -1.0) & (x <= width)
    y_low, y_high, y = _corners(y.clamp(min=0.0), height)
    x_low, x_high, x = _corners(x.clamp(min=0.0), width)
    fraction_y, fraction_x = y - y_low, x - x_low
    weights = torch.stack([(1 - fraction_y) * (1 - fraction_x), (1 - fraction_y) * fraction_x,
                           fraction_y * (1 - fraction_x), fraction_y * fraction_x], dim=-1)
    weights = weights * inside[..., None] / (samples * samples)
    base = (batch * (height * width))[:, None, None, None, None]
    pixels = torch.stack([base + y_low * width + x_low, base + y_low * width + x_high,
                          base + y_high * width + x_low, base + y_high * width + x_high], dim=-1)
    cells = torch.arange(len(rois) * pooled_height * pooled_width, device=rois.device)
    cells = cells.repeat_interleave(samples * samples * CORNERS)
    return pixels.reshape(-1), cells, weights.reshape(-1)


def _corners(coordinate: Tensor, size: int) -> tuple[Tensor, Tensor, Tensor]:
    """Low and high neighbours of clamped sample coordinates, and the coordinate as the kernel uses it."""
    low = coordinate.floor().long()
    at_edge = low >= size - 1
    low = torch.where(at_edge, size - 1, low)
    high = torch.where(at_edge, size - 1, low + 1)
    return low, high, torch.where(at_edge, low.to(coordinate.dtype), coordinate)


def _summation_dtype(dtype: torch.dtype) -> torch.dtype:
    """The type the sparse product sums in: the gradient's, but float32 for a half-precision gradient."""
    return torch.float32 if dtype in (torch.bfloat16, torch.float16) else dtype


def _features_gradient(
    grad_output: Tensor, rois: Tensor, feature_shape: torch.Size, spatial_scale: float, sampling_ratio: int,
) -> Tensor:
    """``M^T @ grad_output``, shaped like the features: (N, C, H, W)."""
    batch_size, channels, height, width = feature_shape
    output_size = (grad_output.shape[2], grad_output.shape[3])
    pixels, cells, weights = bilinear_weights(rois, height, width, output_size, spatial_scale, sampling_ratio)
    order = torch.argsort(pixels)
    row_starts = torch.zeros(batch_size * height * width + 1, dtype=torch.long, device=rois.device)
    row_starts[1:] = torch.cumsum(torch.bincount(pixels, minlength=batch_size * height * width), dim=0)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        transposed = torch.sparse_csr_tensor(
            row_starts, cells[order], weights[order].to(_summation_dtype(grad_output.dtype)),
            (batch_size * height * width, grad_output.shape[0] * output_size[0] * output_size[1]),
            check_invariants=False,
        )
    # the sparse product has no bfloat16 kernel on the CPU: a bfloat16 gradient (autocast) is summed in float32
    rows = grad_output.permute(0, 2, 3, 1).reshape(-1, channels).to(transposed.dtype)
    gradient = transposed @ rows
    gradient = gradient.reshape(batch_size, height, width, channels).permute(0, 3, 1, 2)
    return gradient.to(grad_output.dtype).contiguous()


class _RoIAlignSparseBackward(torch.autograd.Function):
    """torchvision's forward; the backward of :func:`_features_gradient`."""

    @staticmethod
    def forward(ctx, features: Tensor, rois: Tensor, output_size: tuple[int, int], spatial_scale: float,
                sampling_ratio: int) -> Tensor:
        ctx.save_for_backward(rois)
        ctx.settings = (features.shape, spatial_scale, sampling_ratio)
        return roi_align(features, rois, output_size, spatial_scale, sampling_ratio)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_output: Tensor) -> tuple[Tensor | None, ...]:
        (rois,) = ctx.saved_tensors
        feature_shape, spatial_scale, sampling_ratio = ctx.settings
        gradient = _features_gradient(grad_output, rois, feature_shape, spatial_scale, sampling_ratio)
        return gradient, None, None, None, None


def roi_align_fast_backward(
    features: Tensor, rois: Tensor, output_size: tuple[int, int], spatial_scale: float, sampling_ratio: int,
) -> Tensor:
    """``torchvision.ops.roi_align`` (``aligned=False``) with the sparse backward on the CPU.

    Parameters
    ----------
    features : (N, C, H, W) float
    rois : (R, 5) float
        ``(batch_index, x1, y1, x2, y2)`` in input pixels.
    output_size : (PH, PW)
    spatial_scale : float
    sampling_ratio : int

    Returns
    -------
    (R, C, PH, PW) float
    """
    sparse = (features.requires_grad and torch.is_grad_enabled() and features.device.type == "cpu"
              and sampling_ratio > 0 and len(rois) > 0)
    if not sparse:
        return roi_align(features, rois, output_size, spatial_scale, sampling_ratio)
    return _RoIAlignSparseBackward.apply(features, rois, output_size, spatial_scale, sampling_ratio)


class FastMultiScaleRoIAlign(MultiScaleRoIAlign):
    """torchvision's :class:`~torchvision.ops.MultiScaleRoIAlign` pooling each level with
    :func:`roi_align_fast_backward`.

    The same level assignment (``map_levels``, FPN paper eq. 1) and output;
    ``scales`` and ``map_levels`` must be set (the model fixes them from its
    FPN strides), else torchvision's own forward runs.
    """

    def forward(self, x: dict[str, Tensor], boxes: list[Tensor], image_shapes: list[tuple[int, int]]) -> Tensor:
        if self.scales is None or self.map_levels is None:
            return super().forward(x, boxes, image_shapes)
        features = [feature for name, feature in x.items() if name in self.featmap_names]
        rois = convert_boxes_to_roi_format(boxes)
        levels = self.map_levels(boxes)
        result = features[0].new_zeros((len(rois), features[0].shape[1], *self.output_size))
        for level, (feature, scale) in enumerate(zip(features, self.scales, strict=True)):
            chosen = torch.where(levels == level)[0]
            result[chosen] = roi_align_fast_backward(
                feature, rois[chosen], self.output_size, scale, self.sampling_ratio).to(result.dtype)
        return result
