"""Depth-to-colour registration from the data: focal ratio, baseline, and whose intrinsics were given.

An unregistered RGB-D sensor (Kinect v1) hands out depth in the depth camera's pixel grid. Two things
separate it from the colour camera: the focal lengths (``k = f_depth / f_colour``, ~1.114) and the
baseline (the depth camera ~2.5 cm to the side along x). A dataset hands out *one* set of intrinsics,
and which camera they belong to varies: 7-Scenes gives the depth camera's (585 px) for both images,
others give the colour camera's. :mod:`gsslam.frontend.colour_focal` assumed the former; on data that
gives the colour intrinsics it found a compromise (1.076 for 1.114) and then divided the correct colour
focal length by it (docs/results.md, "RGB-D accuracy, session 5").

Here both are estimated from the same evidence (ICP motion of the depth images + colour flow, the
truncated reprojection error of :func:`gsslam.frontend.colour_focal.reprojection_cost`), under two
hypotheses about the given focal length ``f``:

- ``given = "depth"``: the depth camera has ``f`` (ICP once at ``f``), the colour camera ``f / k``;
- ``given = "colour"``: the colour camera has ``f``, the depth camera ``k f`` (ICP rerun at every
  candidate ``k``: back-projecting depth with a wrong focal length stretches the scene sideways, which
  a rigid motion cannot explain, so the focal lengths are observable, not only their ratio).

For each hypothesis ``k`` and the baseline ``b`` are fitted (scans, coordinate descent); the
hypothesis with the smaller error wins. :func:`register_frame` then hands every frame out with the
colour intrinsics and its depth re-projected into the colour camera (z-buffer: the nearest surface
wins), so that later stages see registered RGB-D.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from gsslam.frontend.colour_focal import (
    ICP_STRIDES,
    FlowPair,
    flow_pairs,
    mean_cost,
    pair_icp,
    parabola_min,
)
from gsslam.frontend.depth_reprojection import reproject_depth
from gsslam.frontend.flow import FlowEstimator
from gsslam.frontend.registration_delay import estimate_delay
from gsslam.frontend.registration_edges import EdgeTurn, estimate_turn
from gsslam.frontend.registration_handeye import handeye_baseline
from gsslam.frontend.registration_joint import joint_baseline
from gsslam.frontend.registration_retiming import retime_pairs
from gsslam.geometry import so3_exp
from gsslam.types import CameraIntrinsics, Frame

__all__ = [
    "DepthRegistration", "IDENTITY", "edge_turn_correction", "register_frame", "registration_correction",
    "reproject_depth", "with_delay",
]  # fmt: skip

log = logging.getLogger(__name__)

GIVEN = ("depth", "colour")
K_RANGE = (0.80, 1.25)  # scanned f_depth / f_colour
BASELINE_RANGE_M = 0.06  # scanned |baseline|
COARSE_K_STEP = 0.04  # the colour hypothesis reruns ICP on this grid, then refines
COARSE_ICP_STRIDES = ICP_STRIDES[:-1]  # its coarse grid uses ICP without the finest level


@dataclass(frozen=True)
class DepthRegistration:
    """The depth camera relative to the colour camera, and whose focal length the dataset gave."""

    ratio: float = 1.0  # k = f_depth / f_colour
    baseline_m: float = 0.0  # the depth camera's centre in the colour camera frame, along x (metres)
    given: str = "depth"  # the dataset's fx, fy belong to this camera
    cost: float = float("nan")  # mean truncated reprojection error (px) at this registration
    cost_registered: float = float("nan")  # at k = 1, no baseline (the data taken as registered)
    pairs: int = 0
    points: int = 0
    ok: bool = False  # enough pairs and points, minimum inside the scanned range
    given_by_config: bool = False  # given (encoder.colour_registration_*), not estimated
    pair_baselines_m: tuple[float, ...] = ()  # the baseline fitted to each pair alone at this k (its spread)
    depth_mean_tol: float = 0.0  # reproject_depth's mean_tol (0: the nearest sample)
    depth_interp_tol: float = 0.0  # reproject_depth's interp_tol (0: the pixel a sample lands on)
    baseline_m_fixed_motion: float = float("nan")  # the fit's baseline when the joint or hand-eye one replaced it
    baseline_m_handeye: float = float("nan")  # the hand-eye baseline (registration_handeye), used or not
    handeye_median_chi2: float = float("nan")  # its pairs' agreement (used when <= MAX_MEDIAN_CHI2)
    depth_rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # R_colour_depth's rotation vector (s16)
    delay_s_estimated: float = float("nan")  # depth this long after colour (registration_delay; not applied)
    delay_ok: bool = False  # ... observed and trusted
    delay_std_s: float = float("nan")  # ... its standard deviation
    delay_reason: str = ""  # ... why not ok
    delay_pairs: int = 0  # ... from this many pairs' rotation rates
    delay_rms_deg: tuple[float, float] = (float("nan"), float("nan"))  # ... their residuals' RMS at 0 / tau
    delay_s_whole_image: float = float("nan")  # ... from the whole image's rotations (session 17's; s18)
    delay_bands_s: tuple[float, ...] = ()  # ... from each band of image rows alone (rolling shutter; s18)
    edge_turn: EdgeTurn | None = None  # the turn from depth against colour edges (registration_edges; s17)
    delay_s: float = 0.0  # depth taken this long after colour, as applied (s; session 17, depth_retiming)

    def colour_intrinsics(self, intr: CameraIntrinsics) -> CameraIntrinsics:
        return intr.with_focal(1.0 / self.ratio if self.given == "depth" else 1.0)

    def depth_intrinsics(self, intr: CameraIntrinsics) -> CameraIntrinsics:
        return intr.with_focal(1.0 if self.given == "depth" else self.ratio)

    def R_colour_depth(self) -> np.ndarray | None:  # [3, 3] the depth camera's turn; None: not turned
        if not any(self.depth_rotation_deg):
            return None
        return so3_exp(np.radians(np.asarray(self.depth_rotation_deg, dtype=np.float64)))

    def T_colour_depth(self) -> np.ndarray:  # [4, 4] the depth camera's pose in the colour camera frame
        T = np.eye(4)
        R = self.R_colour_depth()
        if R is not None:
            T[:3, :3] = R
        T[0, 3] = self.baseline_m
        return T

    def is_identity(self) -> bool:
        return self.ratio == 1.0 and self.baseline_m == 0.0 and not any(self.depth_rotation_deg)


IDENTITY = DepthRegistration(ok=True)


def _scan_k(pairs, Ts, intr: CameraIntrinsics, given: str, ks: np.ndarray, b: float) -> np.ndarray:
    out = np.empty(len(ks))
    for j, k in enumerate(ks):
        reg = DepthRegistration(float(k), b, given)
        d = reg.depth_intrinsics(intr)
        out[j] = mean_cost(pairs, Ts, reg.colour_intrinsics(intr), (d.fx, d.fy), b)[0]
    return out


def _fit_fixed_motion(pairs, Ts, intr, given: str, k0: float | None, with_baseline: bool):
    """(k, b, cost, inside) for fixed ICP motions: k scan, then alternating baseline / k scans."""
    if k0 is None:
        ks = np.arange(K_RANGE[0], K_RANGE[1] + 1e-9, 0.0025)
        k, _, inside = parabola_min(ks, _scan_k(pairs, Ts, intr, given, ks, 0.0))
    else:
        k, inside = k0, True
    b = 0.0
    for half_k, half_b, step_b in ((0.04, BASELINE_RANGE_M, 0.0025), (0.01, 0.005, 0.0005))[
        : 2 if with_baseline else 0
    ]:
        bs = np.arange(b - half_b, b + half_b + 1e-9, step_b)
        cb = np.array([_scan_k(pairs, Ts, intr, given, np.array([k]), float(x))[0] for x in bs])
        b, _, _ = parabola_min(bs, cb)
        ks = np.arange(k - half_k, k + half_k + 1e-9, 0.0025)
        k, _, _ = parabola_min(ks, _scan_k(pairs, Ts, intr, given, ks, b))
    cost = float(_scan_k(pairs, Ts, intr, given, np.array([k]), b)[0])
    return k, b, cost, inside


def _fit_depth_given(pairs, intr, with_baseline: bool):
    Ts = [p.T_b_a for p in pairs]
    return _fit_fixed_motion(pairs, Ts, intr, "depth", None, with_baseline)


def _icp_at(pairs, intr: CameraIntrinsics, k: float, strides) -> list[np.ndarray] | None:
    d = intr.with_focal(k)
    Ts = [pair_icp(p, d, strides) for p in pairs]
    return None if any(T is None for T in Ts) else Ts


def _fit_colour_given(pairs, intr, with_baseline: bool):
    """Depth focal ``k f``: ICP on a coarse ``k`` grid, then on a 0.01 grid around its best point.

    At each grid point the baseline (and ``k`` within +-0.04, the ICP motions held at the grid point's)
    is fitted; the grid point's cost is that fitted cost, and ``k`` is the parabola through the fine grid.
    """
    ks = np.arange(K_RANGE[0] + COARSE_K_STEP, K_RANGE[1] - COARSE_K_STEP + 1e-9, COARSE_K_STEP)
    coarse = []
    for k in ks:
        Ts = _icp_at(pairs, intr, float(k), COARSE_ICP_STRIDES)
        coarse.append(
            np.inf if Ts is None else _fit_fixed_motion(pairs, Ts, intr, "colour", float(k), with_baseline)[2]
        )
    j = int(np.argmin(coarse))
    fine_ks = np.arange(ks[j] - COARSE_K_STEP / 2, ks[j] + COARSE_K_STEP / 2 + 1e-9, 0.01)
    fine = []
    for k in fine_ks:
        Ts = _icp_at(pairs, intr, float(k), ICP_STRIDES)
        fine.append(
            (np.inf, 0.0)
            if Ts is None
            else _fit_fixed_motion(pairs, Ts, intr, "colour", float(k), with_baseline)[1:3][::-1]
        )
    costs = np.array([c for c, _ in fine])
    k, cost, _ = parabola_min(fine_ks, costs)
    b = float(fine[int(np.argmin(costs))][1])
    inside = 0 < j < len(ks) - 1 and np.isfinite(cost)
    return k, b, cost, inside


def fit_registration(
    pairs: list[FlowPair],  # from colour_focal.flow_pairs
    intr: CameraIntrinsics,  # as given with the frames
    hypotheses: tuple[str, ...] = GIVEN,
    with_baseline: bool = True,
) -> DepthRegistration:
    """The registration with the smallest reprojection error over ``hypotheses`` (module doc)."""
    if not pairs:
        return DepthRegistration()
    c1, n = mean_cost(pairs, [p.T_b_a for p in pairs], intr, (intr.fx, intr.fy))
    best = DepthRegistration()
    for given in hypotheses:
        fit = _fit_depth_given if given == "depth" else _fit_colour_given
        k, b, cost, inside = fit(pairs, intr, with_baseline)
        log.info("registration if the intrinsics are the %s camera's: k %.4f, baseline %.1f mm, %.3f px",
                 given, k, 1000 * b, cost)  # fmt: skip
        if not cost >= best.cost:  # the first, or a smaller error
            ok = inside and len(pairs) >= 3 and n >= 300
            best = DepthRegistration(float(k), float(b), given, cost, c1, len(pairs), n, ok)
    return best


def estimate_registration(frames: list[Frame], flow: FlowEstimator, **kw) -> DepthRegistration:
    """:func:`fit_registration` on the pairs of ``frames`` (keyword arguments passed on)."""
    return fit_registration(flow_pairs(frames, flow), frames[0].intrinsics, **kw)


def pair_baselines(
    pairs: list[FlowPair], intr: CameraIntrinsics, reg: DepthRegistration
) -> tuple[float, ...]:
    """The baseline that fits each pair alone at ``reg``'s ``k`` (its ICP motion at that focal length).

    Their spread is the estimate's own uncertainty: the baseline moves the predicted flow by ~0.02 px
    (a turn of ``theta`` separates the two camera centres by ``theta b``), so an ICP translation error
    or a flow bias of that size moves it by centimetres (docs/results.md, session 13)."""
    Ts = [p.T_b_a for p in pairs] if reg.given == "depth" else _icp_at(pairs, intr, reg.ratio, ICP_STRIDES)
    if Ts is None:
        return ()
    bs = np.arange(-BASELINE_RANGE_M - 0.04, BASELINE_RANGE_M + 0.04 + 1e-9, 0.002)
    out = []
    for p, T in zip(pairs, Ts):
        cost = np.array([_scan_k([p], [T], intr, reg.given, np.array([reg.ratio]), float(b))[0] for b in bs])
        out.append(round(parabola_min(bs, cost)[0], 5))
    return tuple(out)


def registration_correction(
    frames: list[Frame],
    flow: FlowEstimator,
    min_dev: float,  # |k - 1| that counts as unregistered
    min_baseline_m: float,  # |baseline| that counts as unregistered
    min_gain: float = 0.0,  # ... and only when the fit lowers the error at k = 1, b = 0 by this fraction
    fallback_gap: int | None = None,  # colour_focal.flow_pairs: narrower pairs when the wide ones are few
    joint_weight: float = 0.0,  # > 0: the baseline from motions re-solved with the flow (registration_joint)
    handeye: bool = False,  # the baseline from the colour vs depth motions where pairs agree (registration_handeye)
    delay_s: float = 0.0,  # depth taken this long after colour: the pairs' depth re-timed (registration_retiming)
) -> tuple[DepthRegistration, DepthRegistration | None]:
    """The registration to apply (IDENTITY: leave the frames as they are) and the estimate.

    The depth-given fit runs first (ICP once); only when it finds the data unregistered is the
    colour-given hypothesis (ICP on a grid of focal lengths) tried as well. On registered TUM teddy the
    depth-given fit finds k = 1.00, baseline ~0: nothing changes there. Unregistered means: enough
    evidence (``ok``), ``k`` or ``b`` away from registered, and an error clearly below the registered
    one (``min_gain``: measured 2-4 % on registered teddy playbacks, 34-52 % on unregistered ones;
    docs/results.md, "Depth not registered to colour, session 9"). ``joint_weight`` > 0: an applied
    registration's baseline is then re-fitted with each pair's motion re-solved with its flow, the ICP
    motion a prior of that weight (:mod:`gsslam.frontend.registration_joint`, session 14). ``handeye``: an
    applied registration's baseline is then taken from each pair's colour motion (flow) against its depth
    motion (ICP), pooled by their covariances, where the pairs agree with that model
    (:mod:`gsslam.frontend.registration_handeye`, session 15); else the fit's stays. ``delay_s`` != 0: each
    pair's depth image is first moved to its colour image's time (:mod:`gsslam.frontend.registration_retiming`,
    session 18); 0 runs exactly the code of before.
    """
    if sum(f.depth is not None for f in frames) < 8:
        return IDENTITY, None
    pairs = flow_pairs(frames, flow, fallback_gap=fallback_gap)
    if delay_s:
        pairs, moved = retime_pairs(pairs, frames, delay_s)
        log.info("registration pairs re-timed by %.1f ms: %d of %d", 1e3 * delay_s, moved, len(pairs))
    intr = frames[0].intrinsics

    def unregistered(e: DepthRegistration) -> bool:
        away = abs(e.ratio - 1.0) > min_dev or abs(e.baseline_m) > min_baseline_m
        return e.ok and away and e.cost <= (1.0 - min_gain) * e.cost_registered

    est = fit_registration(pairs, intr, hypotheses=("depth",))
    if unregistered(est):
        est = fit_registration(pairs, intr)
    apply = unregistered(est)
    if apply and joint_weight > 0:
        est = _joint(pairs, intr, est, joint_weight)
    elif apply:
        est = replace(est, pair_baselines_m=pair_baselines(pairs, intr, est))
    if apply and handeye:
        est = _handeye(pairs, intr, est)
    log.info(
        "depth registration: f_depth / f_colour = %.4f, baseline %.1f mm, given intrinsics of the %s camera, "
        "from %d pairs (%d px; %.2f -> %.2f px): %s; baseline of each pair alone (mm): %s",
        est.ratio, 1000 * est.baseline_m, est.given, est.pairs, est.points, est.cost_registered, est.cost,
        "applied" if apply else "not applied", " ".join(f"{1000 * b:.1f}" for b in est.pair_baselines_m),
    )  # fmt: skip
    return (est if apply else IDENTITY), est


def _joint(pairs, intr: CameraIntrinsics, est: DepthRegistration, weight: float) -> DepthRegistration:
    Ts = [p.T_b_a for p in pairs] if est.given == "depth" else _icp_at(pairs, intr, est.ratio, ICP_STRIDES)
    if Ts is None:
        return replace(est, pair_baselines_m=pair_baselines(pairs, intr, est))
    b, alone = joint_baseline(pairs, Ts, est.colour_intrinsics(intr), est.depth_intrinsics(intr), weight)
    log.info("depth registration: baseline %.1f mm from motions re-solved with the flow (fixed motions: %.1f mm)",
             1000 * b, 1000 * est.baseline_m)  # fmt: skip
    return replace(est, baseline_m=float(b), baseline_m_fixed_motion=est.baseline_m, pair_baselines_m=alone)


def _handeye(pairs, intr: CameraIntrinsics, est: DepthRegistration) -> DepthRegistration:
    Ts = [p.T_b_a for p in pairs] if est.given == "depth" else _icp_at(pairs, intr, est.ratio, ICP_STRIDES)
    if Ts is None:
        return est
    he = handeye_baseline(pairs, Ts, est.colour_intrinsics(intr), est.depth_intrinsics(intr), est.baseline_m)
    log.info(
        "depth registration: hand-eye baseline %.1f mm (sd %.1f; pairs' median chi2 %.1f: %s; "
        "the fit's %.1f mm); each pair's (mm): %s", 1000 * he.baseline_m, 1000 * he.std_m, he.median_chi2,
        "used" if he.consistent else "not used", 1000 * est.baseline_m,
        " ".join(f"{1000 * b:.1f}" for b in he.pair_baselines_m),
    )  # fmt: skip
    est = replace(est, baseline_m_handeye=he.baseline_m, handeye_median_chi2=he.median_chi2)
    if not he.consistent:
        return est
    return replace(est, baseline_m=he.baseline_m, baseline_m_fixed_motion=est.baseline_m)


def with_delay(est: DepthRegistration, frames: list[Frame], flow: FlowEstimator) -> DepthRegistration:
    """``est`` with the colour-depth delay estimated over ``frames`` at its registration
    (:mod:`gsslam.frontend.registration_delay`, session 17); recorded, not applied (``delay_s`` is)."""
    intr = frames[0].intrinsics
    d = estimate_delay(frames, flow, est.colour_intrinsics(intr), est.depth_intrinsics(intr), est.baseline_m)
    return replace(
        est, delay_s_estimated=d.delay_s, delay_ok=d.ok, delay_std_s=d.std_s, delay_reason=d.reason,
        delay_pairs=d.pairs, delay_rms_deg=(d.rms_deg_at_zero, d.rms_deg),
        delay_s_whole_image=d.whole_image_delay_s, delay_bands_s=d.band_delays_s,
    )  # fmt: skip


def edge_turn_correction(
    frames: list[Frame], reg: DepthRegistration, est: DepthRegistration, with_baseline: bool = False,
    min_deg: float = 0.0,
) -> tuple[DepthRegistration, DepthRegistration]:
    """The depth camera's turn from edges (:mod:`gsslam.frontend.registration_edges`) at the applied ``k``
    and ``b``, recorded in the estimate and applied where observed and turned at least ``min_deg`` about x or
    y (``reg`` an estimate, not IDENTITY); ``with_baseline``: the turn and the baseline the edges fit
    together are applied instead."""
    intr = frames[0].intrinsics
    turn = estimate_turn(
        frames, reg.depth_intrinsics(intr), reg.colour_intrinsics(intr), reg.baseline_m, len(frames)
    )
    est = replace(est, edge_turn=turn)
    if not turn.observed:
        return reg, est
    if max(abs(turn.rotation_deg[0]), abs(turn.rotation_deg[1])) < min_deg:
        log.info("depth camera's turn from edges below %.2f deg about x and y: not applied", min_deg)
        return reg, est
    if with_baseline:
        reg = replace(reg, baseline_m=turn.baseline_m, baseline_m_fixed_motion=reg.baseline_m)
        return replace(reg, depth_rotation_deg=turn.rotation_deg_with_baseline), est
    return replace(reg, depth_rotation_deg=turn.rotation_deg), est


def register_frame(frame: Frame, reg: DepthRegistration, D_delay: np.ndarray | None = None) -> Frame:
    """``frame`` (with the dataset's intrinsics) with the colour intrinsics and depth in the colour grid.

    ``D_delay`` [4, 4]: the colour camera's motion over the delay between the frame's colour and depth
    images (``reg.delay_s``; :mod:`gsslam.frontend.depth_retiming`): the depth is re-projected with
    ``D_delay @ T_colour_depth``, also where the data is registered (``reg`` the identity). None: no motion.
    """
    if reg.is_identity() and D_delay is None:
        return frame
    intr = frame.intrinsics
    depth = frame.depth
    if depth is not None:
        R, t = reg.R_colour_depth(), None
        if D_delay is not None:
            T = D_delay @ reg.T_colour_depth()
            R, t = T[:3, :3], T[:3, 3]
        depth = reproject_depth(
            depth, reg.depth_intrinsics(intr), reg.colour_intrinsics(intr), reg.baseline_m,
            reg.depth_mean_tol, reg.depth_interp_tol, R, t,
        )  # fmt: skip
    return replace(frame, intrinsics=reg.colour_intrinsics(intr), depth=depth)
