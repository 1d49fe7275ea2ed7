"""togcrf.roi_align: the sparse CPU backward against torchvision's own RoIAlign."""

from __future__ import annotations

import pytest
import torch
from torchvision.ops import MultiScaleRoIAlign, roi_align
from torchvision.ops.poolers import initLevelMapper

from togcrf.roi_align import FastMultiScaleRoIAlign, bilinear_weights, roi_align_fast_backward


def _rois(generator: torch.Generator, count: int, images: int, extent: float) -> torch.Tensor:
    """Boxes of every kind the kernel treats apart: inside, across the border, beyond it, thinner than a pixel."""
    corner = torch.rand(count, 2, generator=generator) * extent * 1.1 - 0.1 * extent
    size = torch.rand(count, 2, generator=generator) * extent * 0.6
    size[: count // 4] *= 0.01  # under one feature pixel: the kernel widens them to one
    batch = torch.randint(0, images, (count, 1), generator=generator).float()
    return torch.cat([batch, corner, corner + size], dim=1)


@pytest.mark.parametrize(("sampling_ratio", "spatial_scale"), [(2, 1 / 8), (1, 1 / 16), (3, 1 / 4)])
def test_gradient_equals_torchvisions(sampling_ratio: int, spatial_scale: float) -> None:
    generator = torch.Generator().manual_seed(sampling_ratio)
    features = torch.randn(3, 5, 13, 17, generator=generator, dtype=torch.float64)
    rois = _rois(generator, 60, 3, 17 / spatial_scale).double()
    grad_output = torch.randn(60, 5, 7, 7, generator=generator, dtype=torch.float64)
    ours = features.clone().requires_grad_()
    output = roi_align_fast_backward(ours, rois, (7, 7), spatial_scale, sampling_ratio)
    output.backward(grad_output)
    reference = features.clone().requires_grad_()
    expected = roi_align(reference, rois, (7, 7), spatial_scale, sampling_ratio)
    expected.backward(grad_output)
    assert torch.equal(output, expected)
    assert ours.grad.abs().max() > 0
    torch.testing.assert_close(ours.grad, reference.grad, rtol=1e-10, atol=1e-10)


def test_the_weights_reproduce_the_forward_pass() -> None:
    generator = torch.Generator().manual_seed(7)
    features = torch.randn(2, 4, 9, 11, generator=generator, dtype=torch.float64)
    rois = _rois(generator, 30, 2, 11 * 8).double()
    pixels, cells, weights = bilinear_weights(rois, 9, 11, (7, 7), 1 / 8, 2)
    rows = features.permute(0, 2, 3, 1).reshape(-1, 4)
    pooled = torch.zeros(30 * 49, 4, dtype=torch.float64).index_add_(0, cells, rows[pixels] * weights[:, None])
    expected = roi_align(features, rois, (7, 7), 1 / 8, 2)
    torch.testing.assert_close(pooled.reshape(30, 7, 7, 4).permute(0, 3, 1, 2), expected)
    assert (weights == 0).any(), "some boxes lie more than a pixel outside the map"


def test_float32_gradient_is_close_and_inference_is_torchvisions() -> None:
    generator = torch.Generator().manual_seed(3)
    features = torch.randn(2, 8, 24, 24, generator=generator)
    rois = _rois(generator, 100, 2, 192.0)
    ours = features.clone().requires_grad_()
    roi_align_fast_backward(ours, rois, (7, 7), 1 / 8, 2).sum().backward()
    reference = features.clone().requires_grad_()
    roi_align(reference, rois, (7, 7), 1 / 8, 2).sum().backward()
    torch.testing.assert_close(ours.grad, reference.grad, rtol=1e-4, atol=1e-5)
    with torch.no_grad():
        assert torch.equal(roi_align_fast_backward(features, rois, (7, 7), 1 / 8, 2),
                           roi_align(features, rois, (7, 7), 1 / 8, 2))


def test_multiscale_pooling_matches_torchvisions_forward_and_backward() -> None:
    generator = torch.Generator().manual_seed(11)
    strides = (8, 16, 32, 64)
    size = 192
    names = [str(level) for level in range(len(strides))]
    maps = {name: torch.randn(2, 6, size // stride, size // stride, generator=generator, dtype=torch.float64)
            for name, stride in zip(names, strides, strict=True)}
    boxes = [_rois(generator, 40, 1, float(size)).double()[:, 1:].clamp(0, size) for _ in range(2)]
    boxes = [torch.cat([b[:, :2], torch.maximum(b[:, 2:], b[:, :2] + 1)], dim=1) for b in boxes]
    results = []
    for pool_class in (FastMultiScaleRoIAlign, MultiScaleRoIAlign):
        pool = pool_class(names, output_size=7, sampling_ratio=2)
        pool.scales = [1.0 / stride for stride in strides]
        pool.map_levels = initLevelMapper(3, 6, canonical_scale=48)  # so that these boxes span levels
        leaves = {name: feature.clone().requires_grad_() for name, feature in maps.items()}
        output = pool(leaves, boxes, [(size, size)] * 2)
        output.backward(torch.ones_like(output))
        results.append((output, [leaves[name].grad for name in names]))
    (ours, our_grads), (expected, expected_grads) = results
    assert torch.equal(ours, expected)
    assert len(set(pool.map_levels(boxes).tolist())) > 1, "the boxes span several levels"
    for our_grad, expected_grad in zip(our_grads, expected_grads, strict=True):
        torch.testing.assert_close(our_grad, expected_grad, rtol=1e-10, atol=1e-10)


def test_bfloat16_gradient_is_summed_in_float32_and_returned_as_bfloat16() -> None:
    """Under CPU autocast (togcrf train --cpu-bf16) the gradient reaching RoIAlign is bfloat16; the sparse
    product has no bfloat16 kernel, so it sums in float32 and hands back the gradient's own type."""
    generator = torch.Generator().manual_seed(5)
    features = torch.randn(2, 8, 20, 20, generator=generator).bfloat16()
    rois = _rois(generator, 50, 2, 160.0)
    ours = features.clone().requires_grad_()
    with torch.autocast("cpu", dtype=torch.bfloat16):  # torchvision's forward pools in float32 under autocast
        output = roi_align_fast_backward(ours, rois, (7, 7), 1 / 8, 2)
    assert output.dtype == torch.bfloat16
    grad_output = torch.randn(output.shape, generator=generator).bfloat16()
    output.backward(grad_output)
    reference = features.float().requires_grad_()
    roi_align(reference, rois, (7, 7), 1 / 8, 2).backward(grad_output.float())
    assert ours.grad.dtype == torch.bfloat16
    assert reference.grad.abs().max() > 0
    torch.testing.assert_close(ours.grad.float(), reference.grad, rtol=1e-2, atol=1e-2)
