"""Small differentiable pose perturbations for keyframe refinement (torch)."""

from __future__ import annotations

import torch


def so3_exp(phi: torch.Tensor) -> torch.Tensor:  # [3] -> [3, 3]
    """Rodrigues' formula, differentiable everywhere (Taylor expansion near zero)."""
    theta2 = (phi * phi).sum()
    zero = torch.zeros((), dtype=phi.dtype, device=phi.device)
    W = torch.stack([zero, -phi[2], phi[1], phi[2], zero, -phi[0], -phi[1], phi[0], zero]).reshape(3, 3)
    if float(theta2.detach()) < 1e-8:
        a, b = 1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0
    else:
        theta = torch.sqrt(theta2)
        a, b = torch.sin(theta) / theta, (1.0 - torch.cos(theta)) / theta2
    return torch.eye(3, dtype=phi.dtype, device=phi.device) + a * W + b * (W @ W)


def se3_delta_matrix(delta: torch.Tensor) -> torch.Tensor:  # [6] (rho, phi) -> [4, 4]
    """``[[Exp(phi), rho], [0, 1]]``: a right perturbation ``T_world_cam @ D`` in the camera frame.

    (A first-order chart of SE(3): the translation is ``rho`` itself, which is all pose refinement by
    small steps needs.)
    """
    top = torch.cat([so3_exp(delta[3:]), delta[:3, None]], dim=1)
    bottom = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=delta.dtype, device=delta.device)
    return torch.cat([top, bottom], dim=0)
