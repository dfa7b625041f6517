"""The time between each frame's colour and depth images, from the two cameras' rotation rates (session 17).

A Kinect v1's colour and depth streams run free: a frame's depth image is taken ``tau`` seconds after its
colour image (``tau > 0``; before: ``tau < 0``; the synthetic dataset's ``depth_delay_s`` has the same sign).
Over consecutive pairs ``(k, k + 2)`` of a stretch of frames:

- the colour camera's rotation ``c_k`` from the flow (``registration_handeye.colour_motion``, ~0.005 deg),
  over the colour images' times ``[t_k, t_k+2]``;
- the depth camera's rotation ``d_k`` from ICP with smoothed normals (``registration_handeye.depth_motion``,
  its covariance), over the depth images' times ``[t_k + tau, t_k+2 + tau]``.

So the depth camera's rotation series is the colour camera's shifted by ``tau``: to first order
``d_kj = s_j (c_kj + (tau / dt) c'_kj)`` per axis ``j``, ``c'`` the series' central difference and ``s_j`` a
scale per axis (ICP's rotations run 1-5 % off on the synthetic Kinect room; left out, that bias would pass for
a delay where the rate is not constant). ``tau`` and ``s`` by alternating weighted least squares (each row by
the two rotations' variances, then Huber), the standard deviation from the residuals' scale.

Only a rotation rate that CHANGES shows ``tau``: at a constant rate the series agree whatever the delay, and
so do the hand-eye pairs' relative motions (measured, docs/results.md session 17: the hand-eye pairs of the
first 40 frames do not see it). Hence a stretch longer than the registration's window, and an honest ``ok``:
enough central differences (``MIN_PAIRS``), the standard deviation at most ``MAX_STD_S`` (a static,
translation-only or constant-rate stretch: "not observed"), the scale of the axis that turns most near 1
(``MAX_SCALE_DEV``) and the estimate within a frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from gsslam.frontend.colour_focal import FlowPair, flow_pairs
from gsslam.frontend.flow import FlowEstimator
from gsslam.frontend.registration_handeye import colour_motion, depth_motion
from gsslam.geometry import so3_log
from gsslam.types import CameraIntrinsics, Frame

log = logging.getLogger(__name__)

GAP = 2  # pair (k, k + GAP), one per frame
BANDS = 3  # bands of image rows the rotations are solved on (rotation_series; the estimate's default)
MIN_PAIRS = 12  # central differences needed
MAX_STD_S = 0.003  # observed: the estimate's standard deviation at most this
MAX_SCALE_DEV = 0.1  # trusted: the scale of the axis that turns most within this of 1
HUBER_SIGMAS = 2.0
FALLBACK_DT_S = 1.0 / 30.0  # the frame interval when the frames carry no usable timestamps


@dataclass(frozen=True)
class DelayEstimate:
    delay_s: float = float("nan")  # tau: the depth image taken this long after its colour image (s)
    std_s: float = float("inf")
    ok: bool = False  # observed and trusted
    reason: str = "no pairs"  # why not ok ("" when ok)
    pairs: int = 0  # central differences used
    scales: tuple[float, float, float] = (float("nan"),) * 3  # ICP's rotation over the flow's, per axis
    rms_deg: float = float("nan")  # the rotation residuals' RMS at the estimate (deg)
    rms_deg_at_zero: float = float("nan")  # ... at tau = 0 (scales refitted)
    frame_dt_s: float = FALLBACK_DT_S
    band_delays_s: tuple[float, ...] = ()  # tau fitted on each band of image rows alone (rotation_series)
    whole_image_delay_s: float = float("nan")  # tau fitted on the whole image's rotations (session 17's)


def frame_interval(frames: list[Frame]) -> float:
    """The median time between consecutive frames (``FALLBACK_DT_S`` without usable timestamps)."""
    ts = np.diff([f.timestamp for f in frames])
    ts = ts[np.isfinite(ts) & (ts > 0)]
    return float(np.median(ts)) if len(ts) else FALLBACK_DT_S


def _scales(C: np.ndarray, dC: np.ndarray, D: np.ndarray, tau_f: float, W: np.ndarray) -> np.ndarray:
    X = C + tau_f * dC  # [N, M] (M: bands x axes)
    return np.sum(W * X * D, 0) / np.maximum(np.sum(W * X * X, 0), 1e-30)


def _solve(C, dC, D, W0, iterations):  # -> tau_f, scales [M], W [N, M], den
    W = W0.copy()
    tau_f, s, den = 0.0, np.ones(C.shape[1]), 0.0
    for _ in range(iterations):
        s = _scales(C, dC, D, tau_f, W)
        g = s[None, :] * dC  # d prediction / d tau_f
        r0 = D - s[None, :] * C
        den = float(np.sum(W * g * g))
        tau_f = float(np.sum(W * g * r0)) / den if den > 1e-30 else 0.0
        z = (D - s[None, :] * (C + tau_f * dC)) * np.sqrt(W0)  # in sigmas
        sig = 1.4826 * float(np.median(np.abs(z))) + 1e-12
        W = W0 * np.minimum(1.0, HUBER_SIGMAS * sig / np.maximum(np.abs(z), 1e-18))
    return tau_f, s, W, den


def _fit_columns(C, dC, D, W0, iterations):  # [N, M] each -> tau_f, std_f, scales [M], rms, rms at 0
    tau_f, s, W, den = _solve(C, dC, D, W0, iterations)
    z = (D - s[None, :] * (C + tau_f * dC)) * np.sqrt(W0)
    s2 = float(np.sum(W / W0 * z * z)) / max(float(np.sum(W / W0)) - 1.0 - C.shape[1], 1.0)  # (sigmas^2)
    std_f = float(np.sqrt(max(s2, 1.0) / den)) if den > 1e-30 else float("inf")
    s0 = _scales(C, dC, D, 0.0, W)
    e, e0 = D - s[None, :] * (C + tau_f * dC), D - s0[None, :] * C
    rms = lambda x: float(np.degrees(np.sqrt(np.sum(W * x * x) / np.sum(W))))  # noqa: E731
    return tau_f, std_f, s, rms(e), rms(e0)


def fit_delay(
    index: np.ndarray,  # [N] each pair's first frame (pairs (k, k + GAP))
    colour_rot: np.ndarray,  # [N, 3] or [N, 1 + B, 3] the colour camera's rotation vectors (rad)
    depth_rot: np.ndarray,  # the same shape: the depth camera's, in the colour camera's axes
    std: np.ndarray,  # the same shape: the two's summed standard deviation per axis (rad)
    frame_dt_s: float,
    iterations: int = 10,
) -> DelayEstimate:
    """``tau`` from the two rotation series (module doc), rows weighted by ``std`` and Huber; pure numpy.

    ``[N, 3]``: the whole image's rotations (session 17). ``[N, 1 + B, 3]`` (``rotation_series(bands=B)``):
    column 0 the whole image's, columns ``1..B`` each band of image rows' (module doc: rolling shutter).
    Then ``tau`` is fitted on the bands, each with its own scales, all sharing ``tau``; the scale check
    and ``whole_image_delay_s`` come from column 0, ``band_delays_s`` from each band alone."""
    k = np.asarray(index, dtype=np.float64)
    C3, D3 = np.asarray(colour_rot, np.float64), np.asarray(depth_rot, np.float64)
    S3 = np.asarray(std, np.float64)
    if C3.ndim == 2:
        C3, D3, S3 = C3[:, None], D3[:, None], S3[:, None]
    inner = np.zeros(len(k), bool)
    inner[1:-1] = (np.diff(k)[:-1] == 1) & (np.diff(k)[1:] == 1)  # both neighbours present
    if inner.sum() < MIN_PAIRS:
        return DelayEstimate(pairs=int(inner.sum()), reason="too few pairs", frame_dt_s=frame_dt_s)
    n = len(k)

    def fit(cols: slice):  # the columns' bands stacked as [N, bands x 3]
        C, D = C3[:, cols].reshape(n, -1), D3[:, cols].reshape(n, -1)
        dC = np.zeros_like(C)
        dC[1:-1] = (C[2:] - C[:-2]) / 2.0  # the central difference (used where both neighbours are)
        W0 = 1.0 / np.maximum(S3[:, cols].reshape(n, -1)[inner], 1e-9) ** 2
        return _fit_columns(C[inner], dC[inner], D[inner], W0, iterations)

    whole = fit(slice(0, 1))
    nb = C3.shape[1] - 1
    tau_f, std_f, _, rms_e, rms_e0 = whole if nb == 0 else fit(slice(1, None))
    bands = tuple(fit(slice(j, j + 1))[0] * frame_dt_s for j in range(1, nb + 1))
    s_whole = whole[2]
    tau, sd = tau_f * frame_dt_s, std_f * frame_dt_s
    if not sd <= MAX_STD_S:
        reason = "not observed"
    elif abs(s_whole[int(np.argmax(np.sum(np.abs(C3[:, 0]), 0)))] - 1.0) > MAX_SCALE_DEV:
        reason = "scales"  # the axis that turns most, over the whole image
    elif abs(tau_f) > 1.0:
        reason = "beyond a frame"
    else:
        reason = ""
    return DelayEstimate(
        tau, sd, reason == "", reason, int(inner.sum()), tuple(float(x) for x in s_whole), rms_e, rms_e0,
        frame_dt_s, bands, whole[0] * frame_dt_s,
    )  # fmt: skip


def band_rows(intr: CameraIntrinsics, ref: CameraIntrinsics, bands: int) -> list[tuple[float, float]]:
    """The rows of ``intr``'s image that see band ``j`` of ``bands`` equal bands of ``ref``'s rows (the same
    elevation of the ray: the two cameras sit side by side, along x)."""
    edges = np.linspace(0.0, ref.height, bands + 1)
    rows = intr.cy + (edges - ref.cy) * intr.fy / ref.fy
    return [(float(rows[j]), float(rows[j + 1])) for j in range(bands)]


def _band_motions(p: FlowPair, colour, depth, baseline_m, cm, dm, bands: int):  # -> [(cm, dm)] or None
    out = []
    for (c0, c1), (d0, d1) in zip(band_rows(colour, colour, bands), band_rows(depth, colour, bands)):
        v = p.uv_a[:, 1]
        sel = (v >= c0) & (v < c1)
        src = np.array(p.raw_a, dtype=np.float32, copy=True)
        src[: max(0, int(np.ceil(d0)))] = np.nan
        src[max(0, int(np.ceil(d1))) :] = np.nan
        cb = colour_motion(replace(p, uv_a=p.uv_a[sel], uv_b=p.uv_b[sel]), colour, (depth.fx, depth.fy),
                           baseline_m, cm[0])  # fmt: skip
        db = depth_motion(src, p.raw_b, depth, dm[0])
        if cb is None or db is None:
            return None
        out.append((cb, db))
    return out


def rotation_series(
    pairs: list[FlowPair],  # (k, k + GAP), FlowPair.index_a = k
    colour: CameraIntrinsics,
    depth: CameraIntrinsics,
    baseline_m: float,
    motions: list[np.ndarray] | None = None,  # [4, 4] each pair's ICP start (depth camera); None: pair.T_b_a
    bands: int = 1,
) -> tuple[np.ndarray, ...]:  # index [N], colour rotations [N, 3] / [N, 1 + B, 3], depth rotations, their sd
    """Each pair's colour (flow) and depth (ICP) rotation where both are found, and the two's summed sd.

    ``bands`` > 1: ``[N, 1 + bands, 3]``: the whole image's, then each rotation solved again on each of
    ``bands`` bands of image rows (the colour camera's flow points in the band, the depth camera's ICP source
    points in the rows that see the same rays), started from the whole image's; a pair where a band fails is
    left out."""
    Tb = np.eye(4)
    Tb[0, 3] = baseline_m
    rows = []
    for j, p in enumerate(pairs):
        T = p.T_b_a if motions is None else motions[j]
        dm = depth_motion(p.raw_a, p.raw_b, depth, T)
        cm = colour_motion(p, colour, (depth.fx, depth.fy), baseline_m, Tb @ T @ np.linalg.inv(Tb))
        if dm is None or cm is None:
            continue
        per = [] if bands <= 1 else _band_motions(p, colour, depth, baseline_m, cm, dm, bands)
        if per is None:
            continue
        per = [(cm, dm)] + per
        sd = [np.sqrt(np.diag(c[1])[3:] + np.diag(d[1])[3:]) for c, d in per]
        rot = [[so3_log(m[0][:3, :3]) for m in cd] for cd in zip(*per)]  # colour, depth: [1 + B] each
        rows.append((p.index_a, rot[0], rot[1], sd))
    if not rows:
        shape = (0, 3) if bands <= 1 else (0, 1 + bands, 3)
        return np.zeros(0), np.zeros(shape), np.zeros(shape), np.zeros(shape)
    out = [np.array([r[j] for r in rows]) for j in (1, 2, 3)]  # [N, 1 + B, 3]
    return (np.array([r[0] for r in rows]), *(x[:, 0] if bands <= 1 else x for x in out))


def estimate_delay(
    frames: list[Frame],  # a stretch of consecutive frames (as the dataset hands them out)
    flow: FlowEstimator,
    colour: CameraIntrinsics,  # the registration's
    depth: CameraIntrinsics,
    baseline_m: float,
    bands: int = BANDS,  # 1: the whole image's rotations only (session 17's estimate)
) -> DelayEstimate:
    """``tau`` over ``frames`` (module doc)."""
    pairs = flow_pairs(
        frames, flow, gap=GAP, max_pairs=len(frames), min_rotation_deg=0.0, icp_refused_ok=True
    )
    est = fit_delay(*rotation_series(pairs, colour, depth, baseline_m, bands=bands), frame_interval(frames))
    log.info(
        "colour-depth delay: %.1f ms (sd %.1f; %d pairs of %d frames; bands %s ms, whole image %.1f ms; "
        "rotation scales %s; rms %.4f deg, at 0: %.4f)%s", 1000 * est.delay_s, 1000 * est.std_s, est.pairs,
        len(frames), " ".join(f"{1000 * x:.1f}" for x in est.band_delays_s), 1000 * est.whole_image_delay_s,
        " ".join(f"{x:.3f}" for x in est.scales), est.rms_deg, est.rms_deg_at_zero,
        "" if est.ok else f": not trusted ({est.reason})",
    )  # fmt: skip
    return est
