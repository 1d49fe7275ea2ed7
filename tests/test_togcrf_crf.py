"""The task CRF (equations 2-4) and the grasp anchors."""

from __future__ import annotations

import math

import pytest
import torch

from togcrf.anchors import (
    ANCHOR_ANGLES,
    CANDIDATES_PER_ROI,
    GRID,
    cell_centres,
    decode,
    encode,
    match,
    roi_anchors,
    wrap_angle,
)
from togcrf.crf import MeanFieldCrf


def random_rectangles(generator: torch.Generator, count: int) -> torch.Tensor:
    xy = torch.rand((count, 2), generator=generator) * 200
    sizes = 5 + torch.rand((count, 2), generator=generator) * 40
    theta = (torch.rand((count, 1), generator=generator) - 0.5) * math.pi
    return torch.cat([xy, sizes, theta], dim=1).double()


def test_encode_decode_round_trip():
    generator = torch.Generator().manual_seed(0)
    rois = torch.tensor([[10.0, 20.0, 90.0, 60.0], [0.0, 0.0, 150.0, 150.0]], dtype=torch.float64)
    anchors = roi_anchors(rois, anchor_size=12.0)
    grasps = random_rectangles(generator, anchors.shape[1])[None].expand_as(anchors)
    decoded = decode(encode(grasps, anchors), anchors)
    assert torch.allclose(decoded[..., :4], grasps[..., :4], atol=1e-9)
    angle_error = wrap_angle(decoded[..., 4] - grasps[..., 4]).abs()
    assert float(angle_error.max()) < 1e-9


def test_anchor_layout_matches_candidate_order():
    rois = torch.tensor([[0.0, 0.0, 70.0, 140.0]])
    anchors = roi_anchors(rois, anchor_size=16.0)
    assert anchors.shape == (1, CANDIDATES_PER_ROI, 5)
    # candidate k = (i * 7 + j) * 4 + a: cell row i (y), column j (x), angle a
    i, j, a = 3, 5, 2
    candidate = anchors[0, (i * GRID + j) * 4 + a]
    assert candidate[0].item() == pytest.approx((j + 0.5) * 10.0)
    assert candidate[1].item() == pytest.approx((i + 0.5) * 20.0)
    assert candidate[4].item() == pytest.approx(ANCHOR_ANGLES[a])


def test_matching_needs_the_cell_and_an_angle_within_22_5_degrees():
    rois = torch.tensor([[0.0, 0.0, 70.0, 70.0]])
    anchors = roi_anchors(rois, anchor_size=16.0)
    # a grasp at the centre of cell (2, 4), at 80 degrees: within 22.5 deg of 67.5 only
    grasp = torch.tensor([[[45.0, 25.0, 20.0, 8.0, math.radians(80.0)]]])
    positive, targets, tasks = match(anchors, rois, grasp, torch.ones(1, 1, dtype=torch.bool),
                                     torch.tensor([[7]]), 12)
    expected = (2 * GRID + 4) * 4 + 3
    assert positive[0].nonzero().flatten().tolist() == [expected]
    assert tasks[0, expected].argmax().item() == 7
    assert torch.allclose(decode(targets[0, expected], anchors[0, expected]), grasp[0, 0], atol=1e-4)
    # -85 degrees wraps to within 22.5 deg of -67.5 (mod 180)
    wrapped = grasp.clone()
    wrapped[..., 4] = math.radians(-85.0)
    positive, _, _ = match(anchors, rois, wrapped, torch.ones(1, 1, dtype=torch.bool), torch.tensor([[7]]), 12)
    assert positive[0].nonzero().flatten().tolist() == [(2 * GRID + 4) * 4 + 0]


def test_crf_without_pairwise_weights_returns_softmax_of_the_logits():
    generator = torch.Generator().manual_seed(1)
    logits = torch.randn((3, CANDIDATES_PER_ROI, 12), generator=generator)
    crf = MeanFieldCrf(12)
    with torch.no_grad():
        crf.omega.zero_()
        crf.mu.zero_()
    # the unary is psi_u = -logits, so Q = softmax(-psi_u) = softmax(logits)
    assert torch.allclose(crf(logits).exp(), torch.softmax(logits, dim=-1), atol=1e-6)


def loop_mean_field_step(logits, marginals, omega, mu, positions, bandwidth):
    """Equation 4 for one RoI, written term by term with Python loops."""
    count, labels = logits.shape
    updated = torch.empty_like(logits)
    for i in range(count):
        for a in range(labels):
            energy = logits[i, a].item()
            for j in range(count):
                if j == i:
                    continue
                kernel = math.exp(-float(((positions[i] - positions[j]) ** 2).sum()) / (2 * bandwidth**2))
                for b in range(labels):
                    energy -= omega[a, b].item() * marginals[j, b].item()
                    energy -= mu[a, b].item() * marginals[j, b].item() * kernel
            updated[i, a] = energy
    return torch.softmax(updated, dim=-1)


def test_one_mean_field_step_equals_a_loop_over_equation_4():
    generator = torch.Generator().manual_seed(2)
    crf = MeanFieldCrf(4, iterations=1, bandwidth=0.3).double()
    with torch.no_grad():
        crf.omega.copy_(torch.randn((4, 4), generator=generator, dtype=torch.float64))
        crf.mu.copy_(torch.randn((4, 4), generator=generator, dtype=torch.float64) * 5)
    # a small case: the first 10 candidates of a RoI, with their own kernel
    count = 10
    positions = cell_centres()[:count].double()
    crf.kernel = crf.kernel[:count, :count]
    logits = torch.randn((2, count, 4), generator=generator, dtype=torch.float64)
    marginals = torch.softmax(torch.randn((2, count, 4), generator=generator, dtype=torch.float64), dim=-1)
    batched = torch.softmax(crf.step(logits, marginals), dim=-1)
    for roi in range(2):
        expected = loop_mean_field_step(logits[roi], marginals[roi], crf.effective_omega(), crf.effective_mu(),
                                        positions, 0.3)
        assert torch.allclose(batched[roi], expected, atol=1e-10)
    # and forward with one iteration starts from Q = softmax(logits)
    first = loop_mean_field_step(logits[0], torch.softmax(logits[0], -1), crf.effective_omega(),
                                 crf.effective_mu(), positions, 0.3)
    assert torch.allclose(crf(logits)[0].exp(), first, atol=1e-10)


def test_gradients_reach_omega_and_mu():
    generator = torch.Generator().manual_seed(3)
    crf = MeanFieldCrf(12)
    logits = torch.randn((4, CANDIDATES_PER_ROI, 12), generator=generator, requires_grad=True)
    targets = torch.randint(0, 12, (4, CANDIDATES_PER_ROI), generator=generator)
    loss = torch.nn.functional.nll_loss(crf(logits).reshape(-1, 12), targets.reshape(-1))
    loss.backward()
    for parameter in (crf.omega, crf.mu, logits):
        assert parameter.grad is not None
        assert float(parameter.grad.abs().sum()) > 0


@pytest.mark.parametrize(("use_omega", "use_mu"), [(True, False), (False, True)])
def test_variants_drop_the_unused_term(use_omega, use_mu):
    crf = MeanFieldCrf(12, use_omega=use_omega, use_mu=use_mu)
    assert (crf.omega is not None) == use_omega
    assert (crf.mu is not None) == use_mu
    names = {name for name, _ in crf.named_parameters()}
    assert names == ({"omega"} if use_omega else set()) | ({"mu"} if use_mu else set())


def test_potts_mu_pulls_a_candidate_towards_its_neighbours_label():
    # all candidates say label 0 except one that slightly prefers label 1: the kernel term flips it
    logits = torch.zeros((1, CANDIDATES_PER_ROI, 2))
    logits[0, :, 0] = 2.0
    logits[0, 100] = torch.tensor([0.0, 0.3])
    crf = MeanFieldCrf(2, use_omega=False, use_mu=True, iterations=5)
    marginals = crf(logits).exp()
    assert marginals[0, 100, 0] > 0.5
    assert torch.softmax(logits[0, 100], -1)[0] < 0.5
