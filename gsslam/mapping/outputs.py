"""Outputs of a map (:class:`gsslam.mapping.state.MapState`): image metrics, PLY, keyframe panels."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import cv2
import numpy as np
import torch

from gsslam.eval.image_metrics import psnr
from gsslam.imaging import ssim as ssim_torch
from gsslam.io.atomic import atomic_path
from gsslam.io.ply import GaussianPly, write_ply
from gsslam.mapping import exposure as X
from gsslam.mapping.gaussians import GaussianModel
from gsslam.mapping.state import MapState, render_keyframe, render_pose
from gsslam.types import CameraIntrinsics, Frame


def _resize_image(img: np.ndarray, w: int, h: int) -> np.ndarray:
    if img.shape[:2] == (h, w):
        return img
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def ssim_float32(a: np.ndarray, b: np.ndarray) -> float:  # a, b [H, W, 3] in [0, 1]
    """SSIM of two images (:func:`gsslam.imaging.ssim`, the metric's one implementation) in float32.

    The metric module computes in float64; at 640x480 that was ~4x slower and agreed to ~1e-6 (the
    native-resolution evaluation's SSIM was most of the outputs stage's time, issue #17).
    """
    with torch.no_grad():
        ta = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))
        tb = torch.from_numpy(np.ascontiguousarray(b, dtype=np.float32))
        return float(ssim_torch(ta, tb))


def evenly_spaced(items: list[int], n: int) -> list[int]:
    """At most ``n`` of ``items``, evenly spaced over the list (first and last kept; all if ``n`` >= len).

    The fixed, reproducible sample of frames the map's input-resolution evaluation scores (issue #17).
    """
    if n <= 0 or not items:
        return []
    if len(items) <= n:
        return list(items)
    if n == 1:
        return [items[0]]
    return [items[int(k)] for k in np.linspace(0, len(items) - 1, n)]


def depth_colormap(depth: np.ndarray, valid: np.ndarray) -> np.ndarray:  # [H, W], [H, W] -> [H, W, 3] BGR
    """Turbo colour map over the 2nd..98th percentile of the valid depths; black elsewhere."""
    lo, hi = np.percentile(depth[valid], [2, 98]) if valid.any() else (0.0, 1.0)
    d8 = (np.clip((depth - lo) / max(hi - lo, 1e-6), 0, 1) * 255).astype(np.uint8)
    dc = cv2.applyColorMap(d8, cv2.COLORMAP_TURBO)
    dc[~valid] = 0
    return dc


def frame_exposure(state: MapState, index: int) -> torch.Tensor | None:
    """The exposure [2, 3] a frame is scored through: a keyframe's own, else the nearest keyframe's
    (:func:`gsslam.mapping.exposure.nearest_exposure`; no pixel of the frame is used); None: identity."""
    if index in state.keyframes:
        return state.keyframes[index].exposure
    if all(kf.exposure is None for kf in state.keyframes.values()):
        return None
    # the first keyframe (the gauge) has None, the identity: it is a candidate like any other
    ident = X.identity(state.device)
    known = {i: ident if kf.exposure is None else kf.exposure for i, kf in state.keyframes.items()}
    return X.nearest_exposure(index, known)


def _colour(out, exposure: torch.Tensor | None) -> np.ndarray:  # -> [H, W, 3] in [0, 1]
    with torch.no_grad():
        return X.apply(out.color, exposure, out.alpha).clamp(0, 1).cpu().numpy()


def evaluate_map(
    state: MapState,
    frames: Iterable[Frame],
    poses: dict[int, np.ndarray],
    native: CameraIntrinsics | None = None,
    progress: Callable[[int], None] | None = None,
    native_only: set[int] | None = None,
) -> dict:
    """PSNR / SSIM (gsslam.eval.image_metrics) of renders vs the images, keyframes and other frames.

    At the mapper resolution (the images resized to it): ``psnr_keyframes``, ``ssim_other``, ...; with
    ``native`` (the input camera) also the map rendered at the input resolution vs the input images:
    ``psnr_keyframes_native``, ... (what papers report). ``frames`` is consumed one at a time (a
    generator keeps memory flat); ``progress(k)`` after the k-th frame. ``native_only``: the frames
    evaluated at the input resolution too (default all; a 640x480 render costs ~16x a 160x120 one).
    ``per_frame_psnr`` / ``per_frame_psnr_native``: frame index -> PSNR at each resolution.
    With per-keyframe exposures (``mapper.exposure``) a keyframe is rendered through its own exposure
    and a held-out frame through the nearest keyframe's (:func:`frame_exposure`); ``exposure`` says so.
    """
    w, h = state.intrinsics.width, state.intrinsics.height
    res: dict[str, list] = {"keyframes": [], "other": [], "keyframes_native": [], "other_native": []}
    per_frame, per_frame_native = {}, {}
    for k, fr in enumerate(frames):
        if fr.index in poses:
            kind = "keyframes" if fr.index in state.keyframes else "other"
            image = fr.image.astype(np.float32)
            expo = frame_exposure(state, fr.index)
            ren = _colour(render_pose(state, poses[fr.index]), expo)
            img = _resize_image(image, w, h)
            p = psnr(ren, img)
            per_frame[fr.index] = p
            res[kind].append((p, ssim_float32(ren, img)))
            if native is not None and (native_only is None or fr.index in native_only):
                ren = _colour(render_pose(state, poses[fr.index], native), expo)
                img = _resize_image(image, native.width, native.height)
                p_native = psnr(ren, img)
                per_frame_native[fr.index] = p_native
                res[kind + "_native"].append((p_native, ssim_float32(ren, img)))
        if progress is not None:
            progress(k + 1)
    stats: dict = {"per_frame_psnr": per_frame, "width": w, "height": h}
    if any(kf.exposure is not None for kf in state.keyframes.values()):
        stats["exposure"] = "keyframes: their own; held-out frames: the nearest keyframe's"
    if native is not None:
        stats.update(
            native_width=native.width, native_height=native.height, per_frame_psnr_native=per_frame_native
        )
    for key, vals in res.items():
        if key.endswith("_native") and native is None:
            continue
        stats[f"n_{key}"] = len(vals)
        stats[f"psnr_{key}"] = float(np.mean([v[0] for v in vals])) if vals else float("nan")
        stats[f"ssim_{key}"] = float(np.mean([v[1] for v in vals])) if vals else float("nan")
    return stats


def save_map_ply(model: GaussianModel, path: str | Path) -> int:
    """Write ``model`` as a 3DGS PLY (unit quaternions); returns the file size in bytes."""
    m = model.detached().to("cpu")
    g = GaussianPly(
        means=m.means.numpy(),
        quats_wxyz=m.normalized_quats.numpy(),
        log_scales=m.log_scales.numpy(),
        opacity_logits=m.opacity_logits.numpy(),
        f_dc=m.sh_dc.numpy(),
    )
    return write_ply(path, g)


def keyframe_panels(state: MapState, out_dir: str | Path, n: int = 4) -> list[Path]:
    """``n`` PNGs ``input | render | depth`` at the mapper resolution, keyframes spread over the run."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    order = state.order
    if not order or n <= 0:
        return []
    picks = sorted({order[int(i)] for i in np.linspace(0, len(order) - 1, min(n, len(order)))})
    paths = []
    for idx in picks:
        out = render_keyframe(state, idx)
        img = (state.keyframe(idx).image.cpu().numpy() * 255).astype(np.uint8)
        ren = (_colour(out, frame_exposure(state, idx)) * 255).astype(np.uint8)
        dc = depth_colormap(out.depth.cpu().numpy(), out.alpha.cpu().numpy() > 0.5)
        p = out_dir / f"keyframe_{idx:06d}.png"
        with atomic_path(p) as tmp:
            cv2.imwrite(str(tmp), np.concatenate([img[..., ::-1], ren[..., ::-1], dc], axis=1))
        paths.append(p)
    return paths


def native_panel(
    state: MapState, frame: Frame, T_world_cam: np.ndarray, intrinsics: CameraIntrinsics, path
) -> Path:
    """One PNG ``input | render | depth`` of ``frame`` at the resolution of ``intrinsics`` (the input's)."""
    out = render_pose(state, T_world_cam, intrinsics)
    img = (_resize_image(frame.image.astype(np.float32), intrinsics.width, intrinsics.height) * 255).astype(
        np.uint8
    )
    ren = (_colour(out, frame_exposure(state, frame.index)) * 255).astype(np.uint8)
    dc = depth_colormap(out.depth.cpu().numpy(), out.alpha.cpu().numpy() > 0.5)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate([img[..., ::-1], ren[..., ::-1], dc], axis=1))
    return path
