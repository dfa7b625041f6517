"""Adam for the mapper's steps, without ``torch.optim``.

The arithmetic is that of ``torch.optim.Adam`` on CPU with its defaults (single-tensor path, no
weight decay, no amsgrad): the same parameters after every step, bit for bit
(``tests/mapping/test_adam.py``). Why a copy: the first ``torch.optim.Adam(...)`` of a process imports
``torch._dynamo`` (1.5-3.8 CPU s measured under load, ~2.5 % of a mapped teddy-200 run's CPU), which
the mapper never uses (issue #17).

Learning rates live in ``param_groups`` (a list of ``{"params": [...], "lr": float}``) and may be
changed between steps, as with torch's optimizers.
"""

from __future__ import annotations

import torch


class Adam:
    """``Adam(groups, eps)``: ``groups`` are dicts of ``params`` (tensors that require grad) and ``lr``."""

    def __init__(self, groups: list[dict], eps: float = 1e-8, betas: tuple[float, float] = (0.9, 0.999)):
        self.param_groups = [{"params": list(g["params"]), "lr": float(g["lr"])} for g in groups]
        self.eps = eps
        self.betas = betas
        self.state: dict[int, tuple[int, torch.Tensor, torch.Tensor]] = {}  # id(param) -> step, m, v

    def zero_grad(self, set_to_none: bool = True) -> None:
        for g in self.param_groups:
            for p in g["params"]:
                if set_to_none:
                    p.grad = None
                elif p.grad is not None:
                    p.grad.zero_()

    @torch.no_grad()
    def step(self) -> None:
        beta1, beta2 = self.betas
        for g in self.param_groups:
            for p in g["params"]:
                if p.grad is None:
                    continue
                n, m, v = self.state.get(id(p)) or (0, torch.zeros_like(p), torch.zeros_like(p))
                n += 1
                m.lerp_(p.grad, 1 - beta1)
                v.mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
                step_size = g["lr"] / (1 - beta1**n)
                denom = (v.sqrt() / (1 - beta2**n) ** 0.5).add_(self.eps)
                p.addcdiv_(m, denom, value=-step_size)
                self.state[id(p)] = (n, m, v)
