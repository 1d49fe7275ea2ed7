"""The fully connected CRF over the task labels of a RoI's grasp candidates (paper, Section IV-C).

Equation 2: ``P(x) = exp(-sum_i psi_u(x_i) - sum_{i != j} psi_p(x_i, x_j)) / Z``
with the unary ``psi_u = -task logits`` and the pairwise potential of
equation 3, ``psi_p(x_i, x_j) = omega(x_i, x_j) + mu(x_i, x_j) k_G(p_i, p_j)``.
Mean-field inference (equation 4) updates every marginal at once::

    Q_i(a) ∝ exp(logit_i(a) - sum_b omega(a, b) sum_{j != i} Q_j(b)
                            - sum_b mu(a, b)    sum_{j != i} Q_j(b) k_G(p_i, p_j))

unrolled for ``iterations`` steps (default 5, REFERENCE section 4) with the
same weights at every step and a softmax between steps, as CRF-as-RNN does.
All RoIs of a batch are updated together with batched matrix products: the
candidates' positions are the same in every RoI, so the 196 x 196 kernel is a
constant buffer.

Positions (our choice): ``p`` is the centre of the candidate's anchor cell in
RoI-normalised coordinates (``(j + 0.5) / 7, (i + 0.5) / 7``), so the kernel
measures closeness relative to the object's size and does not depend on the
regressed (still noisy) centres. The four anchors of one cell share a
position, hence ``k_G = 1`` between them; only ``i == j`` is excluded.
``k_G(p, q) = exp(-|p - q|^2 / (2 bandwidth^2))``, bandwidth default 0.2 (a
fifth of the RoI).

Scaling (our choice, to keep SGD at lr 0.001 stable): the sums of equation 4
run over 195 neighbours, so the learnable parameters are stored per
neighbour: the effective ``omega`` of equation 4 is ``omega / (K - 1)`` and
the effective ``mu`` is ``mu / mean_i sum_{j != i} k_G(p_i, p_j)``. These are
exact reparametrisations of equation 4 (constant factors, exposed as
``omega_scale`` and ``mu_scale``); the stored matrices are on the scale of
logits and their heat maps read like the paper's Fig. 5.

Initialisation (CRF-as-RNN, REFERENCE section 4): ``mu`` Potts-like,
``1 - identity`` (a neighbour with another label costs about one logit);
``omega`` small, ``0.1 * (1 - identity)``.

Variants (Table II): ``use_omega`` / ``use_mu`` switch each term; a switched
off term has its parameter set to ``None``.
"""

from __future__ import annotations

import torch
from torch import nn

from togcrf.anchors import GRID, cell_centres

#: Default number of mean-field iterations (REFERENCE section 4: 5-10).
DEFAULT_ITERATIONS = 5

#: Default gaussian kernel bandwidth, in units of the RoI size (our choice).
DEFAULT_BANDWIDTH = 0.2

#: Initial off-diagonal value of omega (our choice: small, "compatible by default").
OMEGA_INIT = 0.1


def gaussian_kernel(positions: torch.Tensor, bandwidth: float) -> torch.Tensor:
    """``k_G`` between all pairs of positions with a zero diagonal (``i != j`` in eq. 4).

    Parameters
    ----------
    positions : (K, 2) float
    bandwidth : float
        Standard deviation of the gaussian, same unit as ``positions``.

    Returns
    -------
    (K, K) float
    """
    squared = torch.cdist(positions, positions).pow(2)
    kernel = torch.exp(-squared / (2.0 * bandwidth**2))
    return kernel * (1.0 - torch.eye(positions.shape[0], dtype=kernel.dtype))


class MeanFieldCrf(nn.Module):
    """Mean-field inference of the task CRF, batched over RoIs.

    Parameters
    ----------
    task_count : int
        Task labels per candidate: those of the model's vocabulary (Table I: 12).
    use_omega, use_mu : bool
        Include the compatibility term ``omega`` / the kernel term ``mu``.
    iterations : int
        Mean-field steps (shared weights).
    bandwidth : float
        Gaussian kernel bandwidth in RoI units.
    grid : int
        Cells per RoI side; positions as in :func:`togcrf.anchors.cell_centres`.
    """

    def __init__(
        self,
        task_count: int,
        use_omega: bool = True,
        use_mu: bool = True,
        iterations: int = DEFAULT_ITERATIONS,
        bandwidth: float = DEFAULT_BANDWIDTH,
        grid: int = GRID,
    ) -> None:
        super().__init__()
        if iterations < 1:
            raise ValueError(f"the CRF needs at least one mean-field iteration, got {iterations}")
        self.task_count = task_count
        self.iterations = iterations
        self.bandwidth = bandwidth
        positions = cell_centres(grid)
        kernel = gaussian_kernel(positions, bandwidth)
        count = positions.shape[0]
        self.register_buffer("positions", positions, persistent=False)
        self.register_buffer("kernel", kernel, persistent=False)
        self.omega_scale = 1.0 / (count - 1)
        self.mu_scale = float(1.0 / kernel.sum(dim=1).mean())
        off_diagonal = 1.0 - torch.eye(task_count)
        self.omega = nn.Parameter(OMEGA_INIT * off_diagonal) if use_omega else None
        self.mu = nn.Parameter(off_diagonal.clone()) if use_mu else None

    def effective_omega(self) -> torch.Tensor | None:
        """``omega`` of equation 4 (the stored parameter times ``omega_scale``)."""
        return None if self.omega is None else self.omega * self.omega_scale

    def effective_mu(self) -> torch.Tensor | None:
        """``mu`` of equation 4 (the stored parameter times ``mu_scale``)."""
        return None if self.mu is None else self.mu * self.mu_scale

    def step(self, logits: torch.Tensor, marginals: torch.Tensor) -> torch.Tensor:
        """One mean-field update (equation 4), before the softmax.

        Parameters
        ----------
        logits : (R, K, T) float
            Task logits, ``-psi_u``.
        marginals : (R, K, T) float
            Current ``Q``.

        Returns
        -------
        (R, K, T) float
            The new unnormalised log marginals.
        """
        energy = logits
        if self.omega is not None:
            # sum_{j != i} Q_j(b) = total over all j minus Q_i(b)
            others = marginals.sum(dim=1, keepdim=True) - marginals
            energy = energy - others @ self.effective_omega().transpose(0, 1)
        if self.mu is not None:
            neighbours = torch.matmul(self.kernel.to(marginals.dtype), marginals)
            energy = energy - neighbours @ self.effective_mu().transpose(0, 1)
        return energy

    def forward(self, logits: torch.Tensor) -> torch.Tensor:
        """Marginals ``Q`` after the mean-field iterations.

        Parameters
        ----------
        logits : (R, K, T) float
            Task logits of every candidate of every RoI (K = 196).

        Returns
        -------
        (R, K, T) float
            Log marginals ``log Q`` (use ``.exp()`` for probabilities); the
            log is returned so that the task loss is a stable cross entropy.
        """
        if logits.shape[1] != self.kernel.shape[0]:
            raise ValueError(f"the CRF was built for {self.kernel.shape[0]} candidates per RoI, got {logits.shape[1]}")
        log_marginals = torch.log_softmax(logits, dim=-1)
        for _ in range(self.iterations):
            log_marginals = torch.log_softmax(self.step(logits, log_marginals.exp()), dim=-1)
        return log_marginals
