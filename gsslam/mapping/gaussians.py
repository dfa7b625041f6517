"""The Gaussian map: a plain container of per-Gaussian torch tensors.

Parametrization (the one the optimizer sees, and the one 3DGS PLY files store):

- ``means`` [N, 3] world positions;
- ``quats`` [N, 4] rotation quaternions (w, x, y, z), not necessarily normalized;
- ``log_scales`` [N, 3] log of the per-axis standard deviations (world units);
- ``opacity_logits`` [N] logit of the opacity;
- ``sh_dc`` [N, 3] degree-0 spherical-harmonic colour: ``rgb = 0.5 + SH_C0 * sh_dc``.

Each Gaussian also remembers its anchor: ``submap_id`` [N] and ``keyframe_id`` [N] (int64). When the
pose graph moves a submap by a Sim(3) ``T_new_old``, :meth:`GaussianModel.apply_transform` moves the
Gaussians anchored to it rigidly (means, rotations) and rescales them (log-scales).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

from gsslam.errors import GsslamError
from gsslam.geometry import rot_to_quat, split_sim3

SH_C0 = 0.28209479177387814


class GaussianError(GsslamError):
    """Gaussian parameters with inconsistent shapes, or a transform that is not a Sim(3)."""


def quat_multiply(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Hamilton product of (w, x, y, z) quaternions: q1 [..., 4], q2 [..., 4] -> [..., 4]."""
    w1, x1, y1, z1 = q1.unbind(-1)
    w2, x2, y2, z2 = q2.unbind(-1)
    return torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        dim=-1,
    )


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:  # [N, 3] -> [N, 3]
    return (rgb - 0.5) / SH_C0


@dataclass
class GaussianModel:
    """Per-Gaussian tensors, all with first dimension N, on one device."""

    means: torch.Tensor  # [N, 3]
    quats: torch.Tensor  # [N, 4] (w, x, y, z)
    log_scales: torch.Tensor  # [N, 3]
    opacity_logits: torch.Tensor  # [N]
    sh_dc: torch.Tensor  # [N, 3]
    submap_id: torch.Tensor  # [N] int64
    keyframe_id: torch.Tensor  # [N] int64

    PARAMS = ("means", "quats", "log_scales", "opacity_logits", "sh_dc")

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expected = {
            "means": (n, 3),
            "quats": (n, 4),
            "log_scales": (n, 3),
            "opacity_logits": (n,),
            "sh_dc": (n, 3),
            "submap_id": (n,),
            "keyframe_id": (n,),
        }
        for name, shape in expected.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise GaussianError(f"Gaussian field '{name}' must be {list(shape)}, got {list(got)}")

    # ------------------------------------------------------------------ construction
    @staticmethod
    def empty(device: str | torch.device = "cpu") -> GaussianModel:
        z = lambda *s: torch.zeros(*s, device=device)  # noqa: E731
        zi = torch.zeros(0, dtype=torch.int64, device=device)
        return GaussianModel(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, 3), zi, zi.clone())

    @staticmethod
    def from_points(
        points: torch.Tensor,  # [N, 3] world
        rgb: torch.Tensor,  # [N, 3] in [0, 1]
        scales: torch.Tensor,  # [N] isotropic std (world units)
        submap_id: int,
        keyframe_id: int,
        opacity: float = 0.5,
    ) -> GaussianModel:
        """Isotropic Gaussians at ``points`` with the given colours and sizes."""
        n, dev = points.shape[0], points.device
        if rgb.shape != (n, 3) or scales.shape != (n,):
            raise GaussianError(
                f"from_points: need rgb [{n}, 3] and scales [{n}], got "
                f"{list(rgb.shape)} and {list(scales.shape)}"
            )
        if not 0.0 < opacity < 1.0:
            raise GaussianError(f"initial opacity must lie in (0, 1), got {opacity}")
        quats = torch.zeros(n, 4, device=dev)
        quats[:, 0] = 1.0
        return GaussianModel(
            means=points.float().clone(),
            quats=quats,
            log_scales=torch.log(scales.float().clamp_min(1e-6))[:, None].repeat(1, 3),
            opacity_logits=torch.full((n,), math.log(opacity / (1 - opacity)), device=dev),
            sh_dc=rgb_to_sh_dc(rgb.float().clamp(0, 1)),
            submap_id=torch.full((n,), int(submap_id), dtype=torch.int64, device=dev),
            keyframe_id=torch.full((n,), int(keyframe_id), dtype=torch.int64, device=dev),
        )

    # ------------------------------------------------------------------ derived values
    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def scales(self) -> torch.Tensor:  # [N, 3] linear std
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> torch.Tensor:  # [N] in (0, 1)
        return torch.sigmoid(self.opacity_logits)

    @property
    def rgb(self) -> torch.Tensor:  # [N, 3], >= 0
        return (0.5 + SH_C0 * self.sh_dc).clamp_min(0.0)

    @property
    def normalized_quats(self) -> torch.Tensor:  # [N, 4] (w, x, y, z), unit norm
        return self.quats / self.quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    def params(self) -> dict[str, torch.Tensor]:
        return {name: getattr(self, name) for name in self.PARAMS}

    def size_bytes(self) -> int:
        """Bytes of the map as a 3DGS PLY without higher SH bands (17 float32 per Gaussian)."""
        return len(self) * 17 * 4

    # ------------------------------------------------------------------ edits (return new models)
    def detached(self) -> GaussianModel:
        return GaussianModel(**{f.name: getattr(self, f.name).detach().clone() for f in fields(self)})

    def select(self, index: torch.Tensor) -> GaussianModel:
        """The Gaussians picked by a bool mask [N] or an index tensor, detached."""
        return GaussianModel(**{f.name: getattr(self, f.name).detach()[index].clone() for f in fields(self)})

    def cat(self, other: GaussianModel) -> GaussianModel:
        return GaussianModel(
            **{
                f.name: torch.cat([getattr(self, f.name).detach(), getattr(other, f.name).detach()])
                for f in fields(self)
            }
        )

    def to(self, device: str | torch.device) -> GaussianModel:
        return GaussianModel(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    @torch.no_grad()
    def apply_transform(self, submap_id: int, T_new_old: np.ndarray) -> int:
        """Move the Gaussians anchored to ``submap_id`` by the Sim(3) ``T_new_old`` [4, 4], in place.

        ``x -> s R x + t``, rotation ``q -> q_R * q``, ``log_scale -> log_scale + log s``.
        Returns the number of Gaussians moved.
        """
        T = np.asarray(T_new_old, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise GaussianError(f"apply_transform needs a finite 4x4 Sim(3), got shape {T.shape}")
        R, t, s = split_sim3(T)
        if not (s > 0 and np.allclose(R @ R.T, np.eye(3), atol=1e-5)):
            raise GaussianError(
                "apply_transform: T_new_old is not a Sim(3) (scale * rotation, positive scale)"
            )
        mask = self.submap_id == int(submap_id)
        n = int(mask.sum())
        if n == 0:
            return 0
        dev, dt = self.device, self.means.dtype
        Rt = torch.as_tensor(R, dtype=dt, device=dev)
        tt = torch.as_tensor(t, dtype=dt, device=dev)
        qx, qy, qz, qw = rot_to_quat(R)
        qR = torch.tensor([qw, qx, qy, qz], dtype=dt, device=dev)
        self.means.data[mask] = float(s) * self.means.data[mask] @ Rt.T + tt
        self.quats.data[mask] = quat_multiply(qR.expand(n, 4), self.quats.data[mask])
        self.log_scales.data[mask] = self.log_scales.data[mask] + math.log(s)
        return n
