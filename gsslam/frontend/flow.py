"""Dense optical flow between two images: a protocol, OpenCV DIS / Farneback, consistency checks.

Every estimator maps two ``[H, W, 3]`` float images in [0, 1] to a flow ``[H, W, 2]`` in pixels
of the *input* resolution: ``img1[v + flow[v, u, 1], u + flow[v, u, 0]] ~ img0[v, u]``.
Internally the images are downscaled so that ``max(H, W) <= cfg.max_side`` and the flow is
upsampled back (values multiplied by the resize factors).

Flows are memoised by the *identity* of the two input arrays (:class:`PairFlowCache`): the
tracking flow keyframe -> frame is computed once and reused when the encoder and the flow
factors ask for the same pair. An entry lives as long as both images do (weak references), so
the memory follows what the pipeline keeps. Images are treated as immutable: an array changed
in place after a flow call would get the stale flow.

A learned flow network (RAFT-like) plugs in through :func:`register_flow_method`: give a factory
``FlowConfig -> FlowEstimator`` and select it with ``flow.method=<name>`` (see docs/frontend.md).
"""

from __future__ import annotations

import logging
import weakref
from collections.abc import Callable
from typing import Protocol

import cv2
import numpy as np

from gsslam.config import FlowConfig
from gsslam.errors import GsslamError

log = logging.getLogger(__name__)


class FlowError(GsslamError):
    """Flow inputs have the wrong shape/type, or the flow method is unknown."""


class FlowEstimator(Protocol):
    def __call__(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        """``img0``, ``img1``: [H, W, 3] float in [0, 1] -> flow [H, W, 2] (px, input resolution)."""
        ...


_DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


def _to_gray(img: np.ndarray) -> np.ndarray:  # [H, W, 3] or [H, W] float in [0, 1] -> [H, W] float32
    a = np.asarray(img)
    if a.ndim == 3:
        if a.shape[2] != 3:
            raise FlowError(f"images must be [H, W, 3] or [H, W], got {a.shape}")
        # 0.299 R + 0.587 G + 0.114 B (ITU-R 601), ~10x faster than a matrix product
        return cv2.cvtColor(np.ascontiguousarray(a, dtype=np.float32), cv2.COLOR_RGB2GRAY)
    if a.ndim != 2:
        raise FlowError(f"images must be [H, W, 3] or [H, W], got {a.shape}")
    return a.astype(np.float32)


def _quantize(g: np.ndarray) -> np.ndarray:  # [H, W] float in [0, 1] (NaN allowed) -> [H, W] uint8
    g = np.nan_to_num(g, nan=0.0)
    return np.clip(g * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _to_gray_u8(img: np.ndarray) -> np.ndarray:  # [H, W, 3] or [H, W] float in [0, 1] -> [H, W] uint8
    return _quantize(_to_gray(img))


class PairFlowCache:
    """Flows keyed by the identity of an image pair, dropped when either image is freed."""

    def __init__(self) -> None:
        self._entries: dict[tuple[int, int], tuple[weakref.ref, weakref.ref, np.ndarray]] = {}
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray | None:
        e = self._entries.get((id(img0), id(img1)))
        if e is not None and e[0]() is img0 and e[1]() is img1:
            self.hits += 1
            return e[2]
        self.misses += 1
        return None

    def put(self, img0: np.ndarray, img1: np.ndarray, flow: np.ndarray) -> None:
        key = (id(img0), id(img1))
        drop = self._entries.pop
        try:  # the callback removes the entry as soon as one image is garbage collected
            r0 = weakref.ref(img0, lambda _r, k=key: drop(k, None))
            r1 = weakref.ref(img1, lambda _r, k=key: drop(k, None))
        except TypeError:  # an object without weak references: never cached
            return
        self._entries[key] = (r0, r1, flow)


def _check_pair(img0: np.ndarray, img1: np.ndarray) -> None:
    if img0.shape[:2] != img1.shape[:2]:
        raise FlowError(f"flow needs two images of one size, got {img0.shape[:2]} and {img1.shape[:2]}")


def resize_flow(flow: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resample ``flow`` [h, w, 2] to [height, width, 2], rescaling the pixel displacements."""
    h, w = flow.shape[:2]
    if (w, h) == (width, height):
        return flow.astype(np.float32, copy=True)
    out = cv2.resize(flow.astype(np.float32), (width, height), interpolation=cv2.INTER_LINEAR)
    out[..., 0] *= width / w
    out[..., 1] *= height / h
    return out


class _ResizingFlow:
    """Runs ``_compute`` (uint8 gray -> flow) at ``max_side`` and returns full-resolution flow."""

    def __init__(self, max_side: int, cache: bool = True) -> None:
        if max_side < 16:
            raise FlowError(f"flow.max_side must be >= 16, got {max_side}")
        self.max_side = int(max_side)
        self.cache = PairFlowCache() if cache else None

    def _compute(self, g0: np.ndarray, g1: np.ndarray, init: np.ndarray | None) -> np.ndarray:
        raise NotImplementedError  # [h, w] uint8 x2, init [h, w, 2] or None -> [h, w, 2]

    def __call__(self, img0: np.ndarray, img1: np.ndarray, init: np.ndarray | None = None) -> np.ndarray:
        """Flow img0 -> img1; ``init`` [H, W, 2] (optional) is a starting flow, e.g. a chained one."""
        _check_pair(img0, img1)
        H, W = img0.shape[:2]
        use_cache = self.cache is not None and init is None
        flow = self.cache.get(img0, img1) if use_cache else None
        if flow is None:
            flow = self._compute_small(img0, img1, init)
            if use_cache:
                self.cache.put(img0, img1, flow)
        return resize_flow(flow, W, H)

    def _compute_small(self, img0: np.ndarray, img1: np.ndarray, init: np.ndarray | None) -> np.ndarray:
        """Flow at the internal resolution (max side <= ``max_side``): [h, w, 2] in those pixels."""
        H, W = img0.shape[:2]
        g0, g1 = _to_gray(img0), _to_gray(img1)
        f = min(1.0, self.max_side / max(H, W))
        if f < 1.0:  # downscale the float image first: quantising fewer pixels is cheaper
            size = (max(1, int(round(W * f))), max(1, int(round(H * f))))
            g0 = cv2.resize(g0, size, interpolation=cv2.INTER_AREA)
            g1 = cv2.resize(g1, size, interpolation=cv2.INTER_AREA)
        g0, g1 = _quantize(g0), _quantize(g1)
        if init is not None:
            if init.shape != (H, W, 2):
                raise FlowError(f"init flow must be [{H}, {W}, 2], got {init.shape}")
            init = resize_flow(np.nan_to_num(init), g0.shape[1], g0.shape[0])
        return self._compute(g0, g1, init)


class DISFlow(_ResizingFlow):
    """OpenCV Dense Inverse Search flow (Kroeger et al., ECCV 2016), preset ultrafast/fast/medium."""

    def __init__(
        self, preset: str = "medium", max_side: int = 320, finest_scale: int = 0, cache: bool = True
    ) -> None:
        super().__init__(max_side, cache)
        if preset not in _DIS_PRESETS:
            raise FlowError(f"unknown DIS preset {preset!r}; choose one of {sorted(_DIS_PRESETS)}")
        self.preset = preset
        self.finest_scale = finest_scale

    def _compute(self, g0: np.ndarray, g1: np.ndarray, init: np.ndarray | None) -> np.ndarray:
        # A fresh DIS object per call (cheap): OpenCV's keeps state after a call with an initial
        # flow, which changes later results. DIS starts from the flow passed as output argument.
        dis = cv2.DISOpticalFlow_create(_DIS_PRESETS[self.preset])
        if self.finest_scale >= 0:  # the presets stop at level 1 or 2 (half/quarter resolution)
            dis.setFinestScale(self.finest_scale)
        return dis.calc(g0, g1, None if init is None else np.ascontiguousarray(init, dtype=np.float32))


class FarnebackFlow(_ResizingFlow):
    """OpenCV Farneback polynomial-expansion flow (5-level pyramid, 15 px window)."""

    def _compute(self, g0: np.ndarray, g1: np.ndarray, init: np.ndarray | None) -> np.ndarray:
        if init is None:
            return cv2.calcOpticalFlowFarneback(g0, g1, None, 0.5, 5, 15, 3, 5, 1.2, 0)
        flow = np.ascontiguousarray(init, dtype=np.float32)
        return cv2.calcOpticalFlowFarneback(g0, g1, flow, 0.5, 5, 15, 3, 5, 1.2, cv2.OPTFLOW_USE_INITIAL_FLOW)


_FACTORIES: dict[str, Callable[[FlowConfig], FlowEstimator]] = {
    "dis": lambda cfg: DISFlow(cfg.dis_preset, cfg.max_side, cfg.dis_finest_scale),
    "farneback": lambda cfg: FarnebackFlow(cfg.max_side),
}


def register_flow_method(name: str, factory: Callable[[FlowConfig], FlowEstimator]) -> None:
    """Make ``flow.method=<name>`` build ``factory(cfg)``: the slot for a learned flow network."""
    _FACTORIES[name] = factory


def make_flow_estimator(cfg: FlowConfig) -> FlowEstimator:
    if cfg.method not in _FACTORIES:
        raise FlowError(f"unknown flow.method {cfg.method!r}; choose one of {sorted(_FACTORIES)}")
    return _FACTORIES[cfg.method](cfg)


def warp_coords(flow: np.ndarray) -> np.ndarray:  # [H, W, 2] -> [H, W, 2] target pixel (u, v)
    H, W = flow.shape[:2]
    u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    return np.stack([u + flow[..., 0], v + flow[..., 1]], axis=-1)


def sample_bilinear(img: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """``img`` [H, W, C] or [H, W] sampled at ``coords`` [..., 2] (u, v); NaN outside the image."""
    src = np.asarray(img, dtype=np.float32)
    c = coords.astype(np.float32)
    # replicate (not NaN) borders: a NaN neighbour with weight 0 would still poison edge pixels
    out = cv2.remap(src, c[..., 0], c[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    H, W = src.shape[:2]
    inside = (c[..., 0] >= 0) & (c[..., 0] <= W - 1) & (c[..., 1] >= 0) & (c[..., 1] <= H - 1)
    out = out.astype(np.float32)
    out[~inside] = np.nan
    return out


def compose_flows(flow_01: np.ndarray, flow_12: np.ndarray) -> np.ndarray:  # [H, W, 2] x2 -> [H, W, 2]
    """Chained flow 0 -> 2: ``f01(p) + f12(p + f01(p))`` (NaN where the chain leaves the image)."""
    return flow_01 + sample_bilinear(flow_12, warp_coords(flow_01))


def forward_backward_error(flow_fw: np.ndarray, flow_bw: np.ndarray) -> np.ndarray:
    """``|fw(p) + bw(p + fw(p))|`` in pixels: [H, W] (NaN where the target leaves the image)."""
    if flow_fw.shape != flow_bw.shape or flow_fw.ndim != 3 or flow_fw.shape[2] != 2:
        raise FlowError(f"flows must both be [H, W, 2], got {flow_fw.shape} and {flow_bw.shape}")
    bw_at = sample_bilinear(flow_bw, warp_coords(flow_fw))
    return np.linalg.norm(flow_fw + bw_at, axis=-1)


def forward_backward_mask(
    flow_fw: np.ndarray,  # [H, W, 2] img0 -> img1
    flow_bw: np.ndarray,  # [H, W, 2] img1 -> img0
    threshold_px: float,
    relative: float = 0.0,
) -> np.ndarray:  # [H, W] bool
    """Pixels of img0 whose flow is forward-backward consistent and lands inside img1.

    Consistent means ``|fw + bw| < threshold_px + relative * |fw|`` (pixels of the given flows).
    Occluded pixels and flow errors fail the test because the backward flow at their target
    belongs to another surface.
    """
    err = forward_backward_error(flow_fw, flow_bw)
    bound = threshold_px + relative * np.linalg.norm(flow_fw, axis=-1)
    with np.errstate(invalid="ignore"):
        return np.isfinite(err) & (err < bound)


def textured_mask(img: np.ndarray, min_gradient: float = 0.02) -> np.ndarray:  # [H, W, 3] -> [H, W] bool
    """Pixels with a local (5x5 mean) gradient magnitude above ``min_gradient`` (intensity/px)."""
    g = _to_gray_u8(img).astype(np.float32) / 255.0
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = cv2.blur(np.sqrt(gx * gx + gy * gy), (5, 5))
    return mag > min_gradient


def chained_flows(
    imgs: list[np.ndarray],  # [W] images [H, W, 3]
    flow: FlowEstimator,
    fb_threshold_px: float,
    min_gradient: float = 0.02,
) -> tuple[list, list, list]:  # fw, bw [W] of [H, W, 2], valid [W] of [H, W] bool; index 0 None
    """Flows 0 -> i and i -> 0 chained through consecutive frames, and the pixels of frame 0 whose chain
    is forward-backward consistent (``fb_threshold_px`` + 1 % of the flow) and textured (``min_gradient``)."""
    n = len(imgs)
    tex = textured_mask(imgs[0], min_gradient)
    fw, bw, valid = [None] * n, [None] * n, [None] * n
    for i in range(1, n):
        f = flow(imgs[i - 1], imgs[i])
        b = flow(imgs[i], imgs[i - 1])
        fw[i] = f if i == 1 else compose_flows(fw[i - 1], f)
        bw[i] = b if i == 1 else compose_flows(b, bw[i - 1])
        ok = forward_backward_mask(
            np.nan_to_num(fw[i], nan=1e6), np.nan_to_num(bw[i], nan=1e6), fb_threshold_px, relative=0.01
        )
        valid[i] = ok & tex
    return fw, bw, valid
