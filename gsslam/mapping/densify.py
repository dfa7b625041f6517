"""Densification and pruning: a strategy dataclass plus an explicit state dict (gsplat style).

GaussianFlow SLAM drives densify/prune by a *normalized, scale-invariant* per-Gaussian error. For a
Gaussian n observed in a keyframe pair (a, b) with measured flow ``f_n`` at its projection in a and
projected motion ``m_n = pi_b(mu_n) - pi_a(mu_n)``::

    e_n = |m_n - f_n| / (|f_n| + eps)        (eps = 1 px)

i.e. the flow error relative to the motion itself, so it does not depend on the image resolution or
on how far the camera moved. Without flow (e.g. before the second keyframe) the mapper feeds the
photometric analogue ``|I_render - I| / (I + eps)`` at the Gaussian's pixel. The state keeps the running
mean ``E_n`` of these samples. One :meth:`DensifyStrategy.step`:

1. *densify*: Gaussians with ``E_n > densify_error`` after ``min_observations`` samples are cloned when
   their screen radius is small (``< split_radius_px``) and split in two smaller ones otherwise;
2. *prune*: opacity below ``min_opacity``; consistently wrong (``E_n > prune_error`` after
   ``min_observations`` samples); or unsupported (never seen ``min_support`` times by ``min_age`` steps);
3. *cap*: at most ``max_gaussians``: densification stops at the cap and, if still above, the least
   opaque Gaussians go.

The state dict holds tensors of length N aligned with the model: ``err_sum``, ``err_count``, ``seen``,
``age`` and ``max_radius`` (largest screen radius in pixels observed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from gsslam.errors import GsslamError
from gsslam.mapping.gaussians import GaussianModel
from gsslam.mapping.projection import quat_to_rotmat

STATE_KEYS = ("err_sum", "err_count", "seen", "age", "max_radius")


class DensifyError(GsslamError):
    """The densification state does not match the Gaussian model."""


@dataclass(frozen=True)
class DensifyStrategy:
    densify_error: float = 0.5
    prune_error: float = 2.0
    min_observations: int = 3
    min_opacity: float = 0.05
    min_support: int = 1
    min_age: int = 3
    split_radius_px: float = 4.0
    split_factor: float = 1.6  # children's scale = parent scale / split_factor
    max_gaussians: int = 50000

    def initialize_state(self, n: int, device: str | torch.device = "cpu") -> dict[str, torch.Tensor]:
        return {k: torch.zeros(n, device=device) for k in STATE_KEYS}

    def grow_state(self, state: dict[str, torch.Tensor], n_new: int) -> dict[str, torch.Tensor]:
        """State for ``n_new`` Gaussians appended at the end of the model."""
        dev = state["age"].device
        return {k: torch.cat([v, torch.zeros(n_new, device=dev)]) for k, v in state.items()}

    def check_state(self, model: GaussianModel, state: dict[str, torch.Tensor]) -> None:
        for k in STATE_KEYS:
            if k not in state or state[k].shape != (len(model),):
                got = None if k not in state else list(state[k].shape)
                raise DensifyError(f"densify state '{k}' must have shape [{len(model)}], got {got}")

    @torch.no_grad()
    def update_state(
        self,
        state: dict[str, torch.Tensor],
        errors: torch.Tensor,  # [N] normalized error, NaN where the Gaussian was not observed
        radii_px: torch.Tensor | None = None,  # [N] screen radius in pixels (0 = not visible)
    ) -> None:
        """Accumulate one observation of every Gaussian (in place)."""
        ok = torch.isfinite(errors)
        state["err_sum"] += torch.where(ok, errors, torch.zeros_like(errors))
        state["err_count"] += ok.float()
        if radii_px is not None:
            vis = radii_px > 0
            state["seen"] += vis.float()
            state["max_radius"] = torch.maximum(state["max_radius"], radii_px.float())
        else:
            state["seen"] += ok.float()

    def mean_error(self, state: dict[str, torch.Tensor]) -> torch.Tensor:  # [N]
        return state["err_sum"] / state["err_count"].clamp_min(1.0)

    @torch.no_grad()
    def step(
        self,
        model: GaussianModel,
        state: dict[str, torch.Tensor],
        active: torch.Tensor | None = None,  # [N] bool: Gaussians of the current window
        densify_only: bool = False,
        generator: torch.Generator | None = None,  # seeded CPU generator for the split offsets
    ) -> tuple[GaussianModel, dict[str, torch.Tensor], dict[str, int]]:
        """Densify, prune and cap; returns the new (detached) model, its state and counts.

        Only ``active`` Gaussians (default: all) age, densify or get pruned; the cap applies to all.
        ``densify_only``: skip the pruning step (the mapper's final pass prunes by opacity itself).
        """
        self.check_state(model, state)
        if active is None:
            active = torch.ones(len(model), dtype=torch.bool, device=model.device)
        if active.shape != (len(model),):
            raise DensifyError(f"active mask must be [{len(model)}], got {list(active.shape)}")
        state = {k: v.clone() for k, v in state.items()}
        state["age"] += active.float()
        n0 = len(model)
        err = self.mean_error(state)
        enough = (state["err_count"] >= self.min_observations) & active

        # 1. densify, within the budget left under the cap
        cand = torch.nonzero(enough & (err > self.densify_error)).flatten()
        budget = max(0, self.max_gaussians - n0)
        if len(cand) > budget:
            cand = cand[torch.argsort(err[cand], descending=True)[:budget]]
        big = state["max_radius"][cand] >= self.split_radius_px
        split_idx, clone_idx = cand[big], cand[~big]
        model, state = self._clone(model, state, clone_idx)  # appends: original indices stay valid
        model, state = self._split(
            model, state, split_idx, generator
        )  # removes parents, appends two children each

        # 2. prune
        # layout now: originals without split parents, clones, first children, second children
        keep_parent = torch.ones(n0, dtype=torch.bool, device=model.device)
        keep_parent[split_idx] = False
        active = torch.cat([active[keep_parent], active[clone_idx], active[split_idx], active[split_idx]])
        err = self.mean_error(state)
        enough = state["err_count"] >= self.min_observations
        prune = model.opacities < self.min_opacity
        prune |= enough & (err > self.prune_error)
        prune |= (state["age"] >= self.min_age) & (state["seen"] < self.min_support)
        prune &= active
        if densify_only:
            prune &= False
        n_pruned = int(prune.sum())
        model, state = _keep(model, state, ~prune)

        # 3. cap
        n_capped = 0
        if len(model) > self.max_gaussians:
            order = torch.argsort(model.opacities, descending=True)[: self.max_gaussians]
            keep = torch.zeros(len(model), dtype=torch.bool, device=model.device)
            keep[order] = True
            n_capped = len(model) - self.max_gaussians
            model, state = _keep(model, state, keep)
        stats = {
            "cloned": len(clone_idx),
            "split": len(split_idx),
            "pruned": n_pruned,
            "capped": n_capped,
            "before": n0,
            "after": len(model),
        }
        return model, state, stats

    def _clone(self, model, state, idx):
        if len(idx) == 0:
            return model, state
        child = model.select(idx)
        for k in ("err_sum", "err_count"):
            state[k][idx] = 0
        new_state = {k: state[k][idx].clone() for k in STATE_KEYS}
        return model.cat(child), {k: torch.cat([state[k], new_state[k]]) for k in STATE_KEYS}

    def _split(self, model, state, idx, generator=None):
        """Replace each Gaussian in ``idx`` by two, sampled from it, with scales / split_factor."""
        if len(idx) == 0:
            return model, state
        parent = model.select(idx)
        R = quat_to_rotmat(parent.quats)  # [M, 3, 3]
        children = []
        for _ in range(2):
            c = parent.select(torch.arange(len(parent), device=model.device))
            # drawn on the CPU from the map's own generator: the same run gives the same map
            noise = torch.randn(c.means.shape, generator=generator, dtype=c.means.dtype)
            offset = noise.to(c.means.device) * parent.scales
            c.means = parent.means + (R @ offset[..., None])[..., 0]
            c.log_scales = parent.log_scales - math.log(self.split_factor)
            children.append(c)
        keep = torch.ones(len(model), dtype=torch.bool, device=model.device)
        keep[idx] = False
        child_state = {k: state[k][idx].clone() for k in STATE_KEYS}
        child_state["err_sum"].zero_()
        child_state["err_count"].zero_()
        child_state["max_radius"] /= self.split_factor
        model, state = _keep(model, state, keep)
        model = model.cat(children[0]).cat(children[1])
        state = {k: torch.cat([state[k], child_state[k], child_state[k]]) for k in STATE_KEYS}
        return model, state


def _keep(model: GaussianModel, state: dict[str, torch.Tensor], keep: torch.Tensor):
    return model.select(keep), {k: v[keep] for k, v in state.items()}
