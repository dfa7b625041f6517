"""The Gaussian mapper: keyframes in, a 3D Gaussian map (and refined keyframe poses) out.

SING3R-SLAM's global map stage plus GaussianFlow's flow supervision, one window at a time:

1. :meth:`GaussianMapper.add_keyframe` resizes the frame to the mapper resolution (``max_side``),
   renders the current map there and seeds new Gaussians only where the map is unmapped (rendered
   alpha < ``unmapped_alpha``, or the measured surface lies well in front of the rendered one), from the
   submap point map (or the sensor depth), coloured by the image, sized by the pixel footprint.
2. :meth:`GaussianMapper.optimize` runs Adam over the last ``window`` keyframes: colour L1+SSIM,
   inverse-depth L1, depth-normal consistency, scale regularizer, GaussianFlow flow loss on stored
   keyframe pairs, and (intra-submap pose refinement) photometric L1 under the alpha mask plus the
   scale-invariant depth term w.r.t. se(3) deltas on the keyframe poses; then densify/prune
   (:mod:`gsslam.mapping.densify`).
3. :meth:`GaussianMapper.on_poses_updated` moves the Gaussians of submaps the pose graph moved.

Keyframe poses ``T_world_cam`` may be Sim(3) (the scale maps submap units to world units); the camera
itself is the rigid part. All depths the mapper returns are z-depths in world units.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.errors import GsslamError
from gsslam.geometry import invert_T, split_sim3
from gsslam.mapping import losses as L
from gsslam.mapping.densify import DensifyStrategy
from gsslam.mapping.gaussians import GaussianModel
from gsslam.mapping.pose import se3_delta_matrix
from gsslam.mapping.rasterize import RenderOutput, render
from gsslam.types import CameraIntrinsics, Frame

_log = logging.getLogger(__name__)


class MapperError(GsslamError):
    """The mapper was given inconsistent input (unknown keyframe, wrong array shapes, bad device)."""


@dataclass
class _Keyframe:
    index: int
    submap_id: int
    image: torch.Tensor  # [h, w, 3] at mapper resolution
    depth: torch.Tensor  # [h, w] world units, NaN unknown
    R: np.ndarray  # [3, 3] rigid rotation of T_world_cam
    t: np.ndarray  # [3]
    scale: float  # Sim(3) scale of the given pose (submap units -> world)
    delta: torch.Tensor  # [6] se(3) right-perturbation (rho, phi), optimized
    anchor: torch.Tensor  # [6] where the pose prior pulls delta: 0, or the accepted pose-only refinement
    depth_weight: torch.Tensor | None = None  # [h, w] confidence of ``depth`` in [0, 1] (None: all 1)

    @property
    def median_depth(self) -> float:  # world units; sets the translation scale of the pose prior
        d = self.depth[torch.isfinite(self.depth)]
        return float(d.median()) if d.numel() else 1.0


def _resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise MapperError("mapper.device=cuda but torch sees no CUDA device; use mapper.device=auto or cpu")
    if name not in ("cpu", "cuda"):
        raise MapperError(f"mapper.device must be auto, cpu or cuda, got {name!r}")
    return torch.device(name)


def _resize(a: np.ndarray, w: int, h: int, nearest: bool = False) -> np.ndarray:
    if a.shape[1] == w and a.shape[0] == h:
        return a
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_AREA
    return cv2.resize(a, (w, h), interpolation=interp)


def _fill_depth(depth: torch.Tensor) -> torch.Tensor:  # [h, w] NaN holes -> [h, w] filled
    """Depth holes (no sensor / point-map value) filled by inpainting, so they still get Gaussians.

    Those Gaussians carry colour only: the depth losses ignore pixels without a measured depth.
    """
    d = depth.detach().cpu().numpy()
    hole = ~np.isfinite(d)
    if not hole.any() or hole.all():
        return depth
    filled = cv2.inpaint(
        np.nan_to_num(d, nan=0.0).astype(np.float32), hole.astype(np.uint8), 3, cv2.INPAINT_NS
    )
    return torch.as_tensor(np.where(hole, filled, d), device=depth.device)


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` torch CPU threads (``n <= 0``: unchanged), then restore the setting.

    The CPU rasterizer's threads spin when the cores are shared (tracking, other processes): one
    thread was up to 15x faster than two on a busy 2-core machine (docs/mapping.md, "Threads").
    """
    before = torch.get_num_threads()
    if n > 0 and n != before:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


class GaussianMapper:
    """A window-optimized 3D Gaussian map over keyframes; see the module docstring."""

    def __init__(self, cfg: MapperConfig, intrinsics: CameraIntrinsics) -> None:
        if not 0.0 <= cfg.revisit_fraction <= 1.0:
            raise MapperError(f"mapper.revisit_fraction must lie in [0, 1], got {cfg.revisit_fraction}")
        self.cfg = cfg
        self.device = _resolve_device(cfg.device)
        self.full_intrinsics = intrinsics
        factor = min(1.0, cfg.max_side / max(intrinsics.width, intrinsics.height))
        self.intrinsics = intrinsics.scaled(factor)
        self.factor_x = self.intrinsics.width / intrinsics.width
        self.factor_y = self.intrinsics.height / intrinsics.height
        self.K = torch.tensor(self.intrinsics.K, dtype=torch.float32, device=self.device)
        self.model = GaussianModel.empty(self.device)
        self.strategy = DensifyStrategy(
            densify_error=cfg.densify_error,
            prune_error=cfg.prune_error,
            min_opacity=cfg.min_opacity,
            max_gaussians=cfg.max_gaussians,
        )
        self.state = self.strategy.initialize_state(0, self.device)
        self._kfs: dict[int, _Keyframe] = {}
        self._order: list[int] = []
        self._flows: dict[tuple[int, int], tuple[torch.Tensor, torch.Tensor]] = {}
        self._submap_poses: dict[int, np.ndarray] = {}
        self._rng = np.random.default_rng(0)
        self._gen = torch.Generator().manual_seed(0)

    # ------------------------------------------------------------------ properties
    @property
    def num_gaussians(self) -> int:
        return len(self.model)

    @property
    def size_mb(self) -> float:
        return self.model.size_bytes() / 1e6

    @property
    def keyframe_indices(self) -> list[int]:
        return list(self._order)

    def _kf(self, index: int) -> _Keyframe:
        if index not in self._kfs:
            raise MapperError(f"frame {index} is not a mapper keyframe (known: {self._order[-5:]}...)")
        return self._kfs[index]

    # ------------------------------------------------------------------ poses
    def _T_cam_world(self, kf: _Keyframe, with_delta: bool = True) -> torch.Tensor:  # [4, 4]
        T_wc = torch.eye(4, dtype=torch.float32, device=self.device)
        T_wc[:3, :3] = torch.as_tensor(kf.R, dtype=torch.float32, device=self.device)
        T_wc[:3, 3] = torch.as_tensor(kf.t, dtype=torch.float32, device=self.device)
        if with_delta:
            T_wc = T_wc @ se3_delta_matrix(kf.delta)
        R, t = T_wc[:3, :3], T_wc[:3, 3]
        top = torch.cat([R.T, -(R.T @ t)[:, None]], dim=1)
        return torch.cat([top, torch.tensor([[0.0, 0.0, 0.0, 1.0]], device=self.device)], dim=0)

    def refined_poses(self) -> dict[int, np.ndarray]:
        """``T_world_cam`` [4, 4] of every keyframe with its refinement applied (Sim(3) scale kept)."""
        out = {}
        for i in self._order:
            kf = self._kfs[i]
            D = se3_delta_matrix(kf.delta.detach().cpu().double()).numpy()
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = kf.R, kf.t
            T = T @ D
            T[:3, :3] *= kf.scale
            out[i] = T
        return out

    # ------------------------------------------------------------------ rendering
    def _render(self, T_cam_world: torch.Tensor, model: GaussianModel | None = None) -> RenderOutput:
        m = self.model if model is None else model
        return render(
            m.means,
            m.quats,
            m.scales,
            m.opacities,
            m.rgb,
            T_cam_world,
            self.K,
            self.intrinsics.width,
            self.intrinsics.height,
        )

    def render_pose(self, T_world_cam: np.ndarray) -> RenderOutput:
        """Render the map (no gradients) at the mapper resolution from a (rigid or Sim(3)) pose."""
        R, t, _ = split_sim3(np.asarray(T_world_cam, dtype=np.float64))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R.T, -R.T @ t
        with torch.no_grad():
            return self._render(torch.as_tensor(T, dtype=torch.float32, device=self.device))

    # ------------------------------------------------------------------ input
    def add_keyframe(
        self,
        frame: Frame,
        T_world_cam: np.ndarray,  # [4, 4] SE(3) or Sim(3)
        submap_id: int,
        points_cam: np.ndarray | None = None,  # [h, w, 3] in submap units (NaN unknown)
        confidence: np.ndarray | None = None,  # [h, w] in [0, 1]
    ) -> int:
        """Register a keyframe and seed Gaussians in its unmapped pixels; returns how many were added."""
        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise MapperError(f"frame {frame.index}: T_world_cam must be a finite 4x4, got {T.shape}")
        R, t, s = split_sim3(T)
        w, h = self.intrinsics.width, self.intrinsics.height
        weight = None
        image = _resize(frame.image.astype(np.float32), w, h)
        if points_cam is not None:
            if points_cam.ndim != 3 or points_cam.shape[2] != 3:
                raise MapperError(
                    f"frame {frame.index}: points_cam must be [h, w, 3], got {points_cam.shape}"
                )
            depth = _resize(points_cam[..., 2].astype(np.float32), w, h, nearest=True) * s
            if confidence is not None:
                conf = _resize(confidence.astype(np.float32), w, h, nearest=True)
                depth = np.where(conf >= self.cfg.min_confidence, depth, np.nan)
                if self.cfg.depth_confidence_weight:
                    weight = torch.as_tensor(np.clip(conf, 0.0, 1.0), device=self.device)
        elif frame.depth is not None:
            depth = _resize(frame.depth.astype(np.float32), w, h, nearest=True) * s
        else:
            raise MapperError(f"frame {frame.index}: need points_cam or a frame with depth to seed Gaussians")
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
        kf = _Keyframe(
            index=frame.index,
            submap_id=int(submap_id),
            image=torch.as_tensor(image, device=self.device),
            depth=torch.as_tensor(depth, device=self.device),
            R=R,
            t=t,
            scale=s,
            delta=torch.zeros(6, device=self.device),
            anchor=torch.zeros(6, device=self.device),
            depth_weight=weight,
        )
        if frame.index not in self._kfs:
            self._order.append(frame.index)
        self._kfs[frame.index] = kf
        with torch_threads(self.cfg.num_threads):
            if self.cfg.pose_refinement and len(self.model) and frame.index != self._order[0]:
                self.refine_pose(frame.index, self.cfg.pose_iterations)
            return self._seed(kf)

    def refine_pose(self, frame_index: int, iterations: int) -> float:
        """Intra-submap pose refinement of one keyframe against the frozen map; returns the last loss.

        Loss: photometric L1 under the rendered alpha mask + ``lambda_pose_depth`` * scale-invariant
        depth + the prior that anchors the delta to the given pose, w.r.t. the keyframe's se(3) delta
        only. The best delta is kept only when it lowers the data loss by ``pose_min_gain`` (relative);
        otherwise the given pose stands (an imperfect map must not pull a good pose away).
        """
        kf = self._kf(frame_index)
        start = kf.delta.detach().clone()
        kf.delta = start.clone().requires_grad_(True)
        opt = torch.optim.Adam([kf.delta], lr=self.cfg.lr_pose_init)
        m = self.model.detached()
        first = best = value = float("nan")
        best_delta = start
        for _ in range(max(0, iterations)):
            out = self._render(self._T_cam_world(kf), m)
            data = self._pose_loss(out, kf, prior=False)
            value = float(data.detach())
            if first != first:  # nan: the first evaluation is at the given pose
                first = best = value
            elif value < best:
                best, best_delta = value, kf.delta.detach().clone()
            loss = data + self.cfg.pose_init_prior * self._pose_prior(kf)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        accept = best < (1.0 - self.cfg.pose_min_gain) * first
        kf.delta = best_delta if accept else start
        kf.anchor = kf.delta.clone()
        _log.debug(
            "pose refinement of %d: %.4f -> %.4f (%s)",
            frame_index,
            first,
            best,
            "kept" if accept else "rejected",
        )
        return best if accept else first

    def _pose_loss(self, out: RenderOutput, kf: _Keyframe, prior: bool = True) -> torch.Tensor:
        mask = out.alpha.detach() > 0.9
        loss = L.l1(out.color, kf.image, mask) + self.cfg.lambda_pose_depth * L.scale_invariant_depth(
            out.depth, kf.depth, mask
        )
        return loss + self._pose_prior(kf) if prior else loss

    def _pose_prior(self, kf: _Keyframe) -> torch.Tensor:
        """Anchors the delta: ``lambda_pose_prior * (|rho / (r z_med)|^2 + |phi / r|^2)``.

        ``r`` is ``pose_prior_rel``; ``z_med`` the keyframe's median depth.
        """
        r = self.cfg.pose_prior_rel
        return self.cfg.lambda_pose_prior * (
            ((kf.delta[:3] - kf.anchor[:3]) / (r * kf.median_depth)).square().sum()
            + ((kf.delta[3:] - kf.anchor[3:]) / r).square().sum()
        )

    @torch.no_grad()
    def _seed(self, kf: _Keyframe) -> int:
        h, w = kf.depth.shape
        stride = max(1, self.cfg.init_stride)
        unmapped = torch.ones(h, w, dtype=torch.bool, device=self.device)
        if len(self.model):
            out = self._render(self._T_cam_world(kf))
            in_front = torch.isfinite(kf.depth) & (kf.depth < 0.7 * out.depth)
            unmapped = (out.alpha < self.cfg.unmapped_alpha) | in_front
        sel = torch.zeros_like(unmapped)
        oy, ox = (int(v) for v in self._rng.integers(0, stride, size=2))
        sel[oy::stride, ox::stride] = True
        sel &= unmapped
        vv, uu = torch.nonzero(sel, as_tuple=True)
        if len(vv) == 0:
            return 0
        z = _fill_depth(kf.depth)[vv, uu]
        ok = torch.isfinite(z) & (z > 0)
        vv, uu, z = vv[ok], uu[ok], z[ok]
        K = self.intrinsics
        x = (uu.float() - K.cx) / K.fx * z
        y = (vv.float() - K.cy) / K.fy * z
        p_cam = torch.stack([x, y, z], dim=-1)
        T_wc = torch.linalg.inv(self._T_cam_world(kf))
        p_world = p_cam @ T_wc[:3, :3].T + T_wc[:3, 3]
        scales = z / K.fx * stride * 0.6
        new = GaussianModel.from_points(
            p_world, kf.image[vv, uu], scales, kf.submap_id, kf.index, opacity=self.cfg.init_opacity
        )
        room = self.cfg.max_gaussians - len(self.model)
        if room <= 0:
            _log.warning(
                "Gaussian cap %d reached; keyframe %d adds nothing", self.cfg.max_gaussians, kf.index
            )
            return 0
        if len(new) > room:
            new = new.select(torch.randperm(len(new), generator=self._gen)[:room].to(self.device))
        self.model = self.model.cat(new)
        self.state = self.strategy.grow_state(self.state, len(new))
        return len(new)

    def add_flow(
        self,
        frame_a_index: int,
        frame_b_index: int,
        flow: np.ndarray,  # [H, W, 2] full-resolution pixels, a -> b
        valid: np.ndarray,  # [H, W] bool
    ) -> None:
        """Store dense flow between two keyframes (rescaled to the mapper resolution) for the flow loss."""
        self._kf(frame_a_index), self._kf(frame_b_index)
        H, W = self.full_intrinsics.height, self.full_intrinsics.width
        if flow.shape != (H, W, 2) or valid.shape != (H, W):
            raise MapperError(
                f"flow must be [{H}, {W}, 2] and valid [{H}, {W}], got {flow.shape}, {valid.shape}"
            )
        w, h = self.intrinsics.width, self.intrinsics.height
        f = _resize(np.nan_to_num(flow.astype(np.float32)), w, h)
        f = f * np.array([self.factor_x, self.factor_y], dtype=np.float32)
        v = _resize(valid.astype(np.float32), w, h) > 0.99
        self._flows[(frame_a_index, frame_b_index)] = (
            torch.as_tensor(f, device=self.device),
            torch.as_tensor(v, device=self.device),
        )

    # ------------------------------------------------------------------ graph feedback
    def on_poses_updated(
        self, submap_poses: dict[int, np.ndarray], keyframe_poses: dict[int, np.ndarray]
    ) -> int:
        """Follow the pose graph: move Gaussians of moved submaps, reset keyframe poses.

        ``submap_poses``: Sim(3) ``T_world_submap`` [4, 4] per submap id. The first time a submap id
        appears its transform is recorded as the reference; afterwards Gaussians anchored to it move by
        ``T_new @ T_old^-1``. ``keyframe_poses``: new ``T_world_cam`` per keyframe index (their pose
        deltas are reset: the graph is expected to have absorbed :meth:`refined_poses`).
        Returns the number of Gaussians moved.
        """
        moved = 0
        for sid, T_new in submap_poses.items():
            T_new = np.asarray(T_new, dtype=np.float64)
            T_old = self._submap_poses.get(sid)
            self._submap_poses[sid] = T_new.copy()
            if T_old is None or np.allclose(T_old, T_new, atol=1e-9):
                continue
            moved += self.model.apply_transform(sid, T_new @ invert_T(T_old))
        for idx, T in keyframe_poses.items():
            if idx not in self._kfs:
                continue
            kf = self._kfs[idx]
            R, t, s = split_sim3(np.asarray(T, dtype=np.float64))
            if abs(s - kf.scale) > 1e-9:
                kf.depth = kf.depth * (s / kf.scale)
            kf.R, kf.t, kf.scale = R, t, s
            kf.delta = torch.zeros(6, device=self.device)
            kf.anchor = torch.zeros(6, device=self.device)
        return moved

    # ------------------------------------------------------------------ optimization
    def _window(self) -> list[int]:
        return self._order[-self.cfg.window :]

    def optimize(self, iterations: int | None = None) -> dict:
        """Adam over the window's keyframes (plus revisits of older ones), then densify/prune; returns stats.

        Steps alternate between the newest keyframe and a random one of the window; a share
        ``revisit_fraction`` of the steps goes to a random keyframe older than the window instead, so
        regions seen earlier do not degrade. Only the newest ``pose_window`` keyframes (never the very
        first, the gauge) get joint pose refinement.
        """
        cfg = self.cfg
        iters = cfg.iterations if iterations is None else int(iterations)
        win = self._window()
        if not win or len(self.model) == 0 or iters <= 0:
            return {"iterations": 0, "num_gaussians": len(self.model)}
        old = self._order[: -len(win)]
        pose_kfs = (
            [i for i in win[-max(0, cfg.pose_window) :] if i != self._order[0]] if cfg.pose_refinement else []
        )
        if cfg.pose_window <= 0:
            pose_kfs = []

        def pick(it: int) -> int:
            if old and self._rng.random() < cfg.revisit_fraction:
                return old[int(self._rng.integers(len(old)))]
            return win[-1] if it % 2 == 0 else win[int(self._rng.integers(len(win)))]

        t0 = time.perf_counter()
        with torch_threads(cfg.num_threads):
            first, last = self._adam(iters, pick, pose_kfs, win)
            active = torch.isin(self.model.keyframe_id, torch.tensor(win, device=self.device))
            self.model, self.state, dstats = self.strategy.step(self.model, self.state, active=active)
        dt = time.perf_counter() - t0
        return {
            "iterations": iters,
            "seconds": dt,
            "ms_per_iteration": 1000 * dt / iters,
            "psnr_first": first,
            "psnr_last": last,
            "num_gaussians": len(self.model),
            **dstats,
        }

    def finalize(self, iterations: int | None = None) -> dict:
        """Global refinement at the end of a run: Adam over *all* keyframes (random order, poses fixed).

        ``iterations`` defaults to ``final_iterations``. Learning rates decay to 10 % over the pass;
        afterwards only transparent Gaussians are pruned (no densification). Returns stats.
        """
        iters = self.cfg.final_iterations if iterations is None else int(iterations)
        if not self._order or len(self.model) == 0 or iters <= 0:
            return {"iterations": 0, "num_gaussians": len(self.model)}
        order = list(self._order)
        # every keyframe once per epoch, shuffled, so none is left out of a short pass
        queue: list[int] = []

        def pick(it: int) -> int:
            if not queue:
                queue.extend(order[int(j)] for j in self._rng.permutation(len(order)))
            return queue.pop()

        t0 = time.perf_counter()
        rounds = max(0, self.cfg.final_densify_rounds)
        bounds = np.linspace(0, iters, rounds + 2).round().astype(int)
        densified = 0
        first = last = None
        with torch_threads(self.cfg.num_threads):
            # errors from the run so far describe a map that no longer exists: start counting afresh
            for k in ("err_sum", "err_count", "max_radius"):
                self.state[k] = torch.zeros_like(self.state[k])
            for r in range(rounds + 1):
                n = int(bounds[r + 1] - bounds[r])
                if n <= 0:
                    continue
                lr0 = 0.1 ** (bounds[r] / max(1, iters - 1))
                f, last = self._adam(n, pick, [], order, decay=0.1 ** (n / max(1, iters - 1)), lr_scale=lr0)
                first = f if first is None else first
                if r < rounds:  # densify where the whole map still errs; no error-based pruning
                    self.model, self.state, st = self.strategy.step(self.model, self.state, densify_only=True)
                    densified += st["cloned"] + st["split"]
                    for k in ("err_sum", "err_count", "max_radius"):
                        self.state[k] = torch.zeros_like(self.state[k])
        keep = self.model.opacities >= self.cfg.min_opacity
        pruned = int((~keep).sum())
        self.model = self.model.select(keep)
        self.state = {k: v[keep] for k, v in self.state.items()}
        dt = time.perf_counter() - t0
        return {
            "iterations": iters,
            "seconds": dt,
            "ms_per_iteration": 1000 * dt / iters,
            "psnr_first": first,
            "psnr_last": last,
            "pruned": pruned,
            "densified": densified,
            "num_gaussians": len(self.model),
        }

    def _adam(
        self, iters: int, pick, pose_kfs: list[int], win: list[int], decay: float = 1.0, lr_scale: float = 1.0
    ):
        """``iters`` Adam steps on the keyframes ``pick(it)`` returns; returns (first, last) step PSNR.

        Learning rates start at ``lr_scale`` x the configured ones and fall exponentially to ``decay`` x
        their start over the steps.
        """
        cfg = self.cfg
        params = {k: v.detach().clone().requires_grad_(True) for k, v in self.model.params().items()}
        for k, v in params.items():
            setattr(self.model, k, v)
        lrs = {
            "means": cfg.lr_means,
            "quats": cfg.lr_quats,
            "log_scales": cfg.lr_scales,
            "opacity_logits": cfg.lr_opacity,
            "sh_dc": cfg.lr_colors,
        }
        groups = [{"params": [params[k]], "lr": lr_scale * lrs[k]} for k in params]
        for i in pose_kfs:
            self._kfs[i].delta = self._kfs[i].delta.detach().clone().requires_grad_(True)
        if pose_kfs:
            groups.append({"params": [self._kfs[i].delta for i in pose_kfs], "lr": cfg.lr_pose})
        opt = torch.optim.Adam(groups, eps=1e-15)
        base = [g["lr"] for g in opt.param_groups]
        gamma = decay ** (1.0 / max(1, iters - 1))
        first = last = None
        for it in range(iters):
            idx = pick(it)
            loss, psnr_val = self._step_loss(self._kfs[idx], pose=idx in pose_kfs, win=win)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if decay != 1.0:
                for g, lr0 in zip(opt.param_groups, base):
                    g["lr"] = lr0 * gamma ** (it + 1)
            first = psnr_val if first is None else first
            last = psnr_val
        for i in pose_kfs:
            self._kfs[i].delta = self._kfs[i].delta.detach()
        self.model = self.model.detached()
        return first, last

    def _step_loss(self, kf: _Keyframe, pose: bool, win: list[int]) -> tuple[torch.Tensor, float]:
        cfg, m = self.cfg, self.model
        T_cw = self._T_cam_world(kf, with_delta=True)
        out = self._render(T_cw)
        loss = L.color_loss(out.color, kf.image, cfg.lambda_ssim)
        unit = kf.median_depth if cfg.depth_scale_free else 1.0
        loss = loss + cfg.lambda_depth * L.inverse_depth_l1(
            out.depth, kf.depth, weight=kf.depth_weight, unit=unit
        )
        if cfg.lambda_depth_normal > 0:
            loss = loss + cfg.lambda_depth_normal * L.depth_normal_consistency(
                out.depth, out.normal, self.K, mask=out.alpha.detach() > 0.5
            )
        loss = loss + cfg.lambda_scale * L.scale_regularizer(m.log_scales)
        if pose:
            loss = loss + self._pose_loss(out, kf)
        # GaussianFlow: projected motion of the Gaussians vs measured flow, for pairs starting here
        err = None
        for (a, b), (flow, valid) in self._flows.items():
            if a != kf.index or b not in win or cfg.lambda_flow <= 0:
                continue
            kb = self._kfs[b]
            uv_b = self._project(
                m.means, self._T_cam_world(kb, with_delta=b in win and kb.delta.requires_grad)
            )
            vis = self._visible(out)
            fl, e, _ = L.flow_loss(
                out.means2d,
                uv_b,
                flow,
                valid,
                weight=vis.float(),
                sigma=cfg.flow_sigma_px,
                inlier_prior=cfg.flow_inlier_prior,
                outlier_range=cfg.flow_outlier_range_px,
            )
            loss = loss + cfg.lambda_flow * fl
            err = e if err is None else torch.where(torch.isfinite(e), e, err)
        with torch.no_grad():
            if err is None:  # photometric analogue of the normalized error, at the Gaussians' pixels
                vis = self._visible(out)
                diff = (out.color - kf.image).abs().mean(-1) / (kf.image.mean(-1) + 0.1)
                e = L.sample_image(diff[..., None], out.means2d.detach())[:, 0]
                err = torch.where(vis, e, torch.full_like(e, float("nan")))
            radius = torch.where(self._visible(out), out.radii.float(), torch.zeros_like(err))
            self.strategy.update_state(self.state, err, radius)
            psnr_val = float(L.psnr(out.color.detach().clamp(0, 1), kf.image))
        return loss, psnr_val

    def _project(self, means: torch.Tensor, T_cam_world: torch.Tensor) -> torch.Tensor:  # [N, 3] -> [N, 2]
        p = means @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        z = p[:, 2].clamp_min(1e-3)
        return torch.stack(
            [self.K[0, 0] * p[:, 0] / z + self.K[0, 2], self.K[1, 1] * p[:, 1] / z + self.K[1, 2]], -1
        )

    @torch.no_grad()
    def _visible(self, out: RenderOutput) -> torch.Tensor:
        """Gaussians drawn in this view and not hidden behind the rendered surface -> [N] bool."""
        d = L.sample_image(out.depth.detach()[..., None], out.means2d.detach())[:, 0]
        return (out.radii > 0) & (out.depths.detach() <= 1.1 * d + 1e-3)

    # ------------------------------------------------------------------ outputs
    @torch.no_grad()
    def render_keyframe(self, frame_index: int) -> RenderOutput:
        """Render a keyframe (with its refined pose) at the mapper resolution."""
        return self._render(self._T_cam_world(self._kf(frame_index)))

    def keyframe_image(self, frame_index: int) -> np.ndarray:  # [h, w, 3] at the mapper resolution
        return self._kf(frame_index).image.cpu().numpy()

    def rendered_depth(self, frame_index: int) -> np.ndarray:
        """Rendered z-depth [H, W] at full resolution, world units, NaN where the map is empty."""
        out = self.render_keyframe(frame_index)
        d = torch.where(out.alpha > 0.5, out.depth, torch.full_like(out.depth, float("nan")))
        W, H = self.full_intrinsics.width, self.full_intrinsics.height
        return _resize(d.cpu().numpy().astype(np.float32), W, H, nearest=True)

    def depth_feedback(self, frame_index: int, n_points: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to ``n_points`` well-covered pixels of a keyframe: (uv [N, 2] full-res px, depth [N] world)."""
        out = self.render_keyframe(frame_index)
        ok = (out.alpha > 0.95) & (out.depth > 0)
        vv, uu = (a.cpu().numpy() for a in torch.nonzero(ok, as_tuple=True))
        if len(vv) > n_points:
            pick = self._rng.choice(len(vv), size=n_points, replace=False)
            vv, uu = vv[pick], uu[pick]
        depth = out.depth.cpu().numpy()[vv, uu].astype(np.float64)
        uv = np.stack([(uu + 0.5) / self.factor_x - 0.5, (vv + 0.5) / self.factor_y - 0.5], axis=1)
        return uv, depth

    def evaluate(self, frames: list[Frame], poses: dict[int, np.ndarray]) -> dict:
        """PSNR / SSIM at the mapper resolution of keyframes and held-out frames with a pose."""
        from gsslam.mapping.outputs import evaluate_map

        with torch_threads(self.cfg.num_threads):
            return evaluate_map(self, frames, poses)

    def save_ply(self, path: str | Path) -> int:
        """Write the map as a 3DGS PLY; returns the file size in bytes."""
        from gsslam.mapping.outputs import save_map_ply

        return save_map_ply(self.model, path)

    def render_keyframe_panels(self, out_dir: str | Path, n: int = 4) -> list[Path]:
        """Write ``n`` PNGs, input | render | depth (turbo colour map), for keyframes spread over the run."""
        from gsslam.mapping.outputs import keyframe_panels

        return keyframe_panels(self, out_dir, n)
