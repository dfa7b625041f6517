"""The mapper's Adam is torch.optim.Adam's arithmetic: the same parameters after every step, bit for bit."""

from __future__ import annotations

import subprocess
import sys

import torch

from gsslam.mapping.adam import Adam


def _loss(params):
    a, b = params
    return (a.sin() * 3.0).square().sum() + (b - 0.3).abs().sum() + (a[:4, 0] * b[:4]).sum()


def test_same_parameters_as_torch_adam_with_changing_learning_rates():
    g = torch.Generator().manual_seed(0)
    init = [torch.randn(50, 3, generator=g), torch.randn(50, generator=g)]
    runs = []
    for cls in (torch.optim.Adam, Adam):
        ps = [t.clone().requires_grad_(True) for t in init]
        opt = cls([{"params": [ps[0]], "lr": 1e-2}, {"params": [ps[1]], "lr": 5e-2}], eps=1e-15)
        base = [gr["lr"] for gr in opt.param_groups]
        history = []
        for it in range(25):
            opt.zero_grad(set_to_none=True)
            _loss(ps).backward()
            if it % 7 == 3:
                ps[1].grad = None  # a parameter without gradient this step is left alone
            opt.step()
            for gr, lr0 in zip(opt.param_groups, base):
                gr["lr"] = lr0 * 0.9 ** (it + 1)  # the mapper's decay
            history.append([p.detach().clone() for p in ps])
        runs.append(history)
    for step_t, step_o in zip(*runs):
        for t, o in zip(step_t, step_o):
            assert torch.equal(t, o)
    assert not torch.equal(runs[1][-1][0], init[0])  # it moved


def test_the_mapper_step_does_not_import_dynamo():
    code = (
        "import sys, torch\n"
        "from gsslam.mapping.adam import Adam\n"
        "p = torch.zeros(3, requires_grad=True)\n"
        "opt = Adam([{'params': [p], 'lr': 0.1}])\n"
        "p.sum().backward(); opt.step()\n"
        "print('torch._dynamo' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
