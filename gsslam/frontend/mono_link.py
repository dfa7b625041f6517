"""The mono scale link: one submap's units against the previous one's, through their shared frame.

A mono submap is put in the previous submap's units by comparing the two depth maps of the frame they
share: ``D(i-1, K)`` (the previous submap's triangulation of it) and ``D(i, 0)`` (this submap's),
``log s_i = log D(i-1, K) - log D(i, 0)`` per pixel. Each depth map is biased against its own submap's
translations by that submap's rotation error over its parallax (a rotation error d at parallax p
shifts a triangulated depth by ~d/p: docs/results.md, "Drift on harder sequences, session 6"), so the
pixels seen at high parallax in BOTH submaps carry the least biased link. The encoder's confidence is
that parallax / (4 ``min_parallax_deg``) (:func:`gsslam.frontend.mono_depth.dense_depth`).

:func:`estimate_link` gives the link as a weighted median of the per-pixel log ratios, each pixel
weighted by the lower of its two confidences, and its standard error: the weighted spread of the
log ratios over the square root of an effective number of independent pixels (neighbouring pixels
of one triangulation share their error; ``independent_pixels`` caps it). ``sigma`` is reported in the
encoding's ``meta["link_sigma"]`` for the measuring tools (``tests/accuracy/chain_links.py``); the graph
does not read it (docs/results.md, "Mono scale chain, session 10": it is far below the links' real error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INDEPENDENT_PIXELS = 50.0  # at most this many independent pixels in a link's standard error


@dataclass(frozen=True)
class Link:
    log_scale: float  # log(D(i-1, K) / D(i, 0)): multiply this submap's units by exp() to chain it
    sigma: float  # standard error of log_scale
    pixels: int  # pixels used
    spread: float  # weighted robust std of the per-pixel log ratios


def weighted_median(x: np.ndarray, w: np.ndarray) -> float:  # [N], [N] >= 0
    """The value where the cumulative weight of the sorted ``x`` reaches half (the lower one on a tie)."""
    order = np.argsort(x)
    cw = np.cumsum(w[order])
    return float(x[order][np.searchsorted(cw, 0.5 * cw[-1])])


def estimate_link(
    depth_prev: np.ndarray,  # [h, w] D(i-1, K), previous submap's units (NaN / <= 0: none)
    depth_new: np.ndarray,  # [h, w] D(i, 0), this submap's units
    conf_prev: np.ndarray | None,  # [h, w] in [0, 1]: depth_prev's confidence (None: all 1)
    conf_new: np.ndarray | None,  # [h, w] in [0, 1]: depth_new's confidence
    min_confidence: float = 0.0,  # pixels whose lower confidence is below this are not used
    independent_pixels: float = INDEPENDENT_PIXELS,
    min_pixels: int = 20,
) -> Link | None:
    """The confidence-weighted link of two depth maps of one frame (None: fewer than ``min_pixels``)."""
    a = np.asarray(depth_prev, np.float64)
    b = np.asarray(depth_new, np.float64)
    ok = np.isfinite(a) & (a > 0) & np.isfinite(b) & (b > 0)
    ca = np.ones_like(a) if conf_prev is None else np.nan_to_num(np.asarray(conf_prev, np.float64))
    cb = np.ones_like(b) if conf_new is None else np.nan_to_num(np.asarray(conf_new, np.float64))
    w = np.minimum(ca, cb)
    ok &= (w > 0) & (w >= min_confidence)
    if ok.sum() < min_pixels:
        return None
    x = np.log(a[ok]) - np.log(b[ok])
    w = w[ok]
    m = weighted_median(x, w)
    spread = 1.4826 * weighted_median(np.abs(x - m), w)
    n_eff = min(float(w.sum() ** 2 / (w**2).sum()), independent_pixels)
    return Link(m, float(spread / np.sqrt(n_eff)), int(ok.sum()), float(spread))


def chain_link(
    sd: np.ndarray,  # [h, w] the shared depth, previous submap's units (NaN: none)
    z0: np.ndarray,  # [h, w] this submap's dense frame-0 depth
    sc: np.ndarray | None,  # [h, w] sd's confidence (None: not handed on)
    c0: np.ndarray,  # [h, w] z0's confidence
    cfg,  # EncoderConfig: min_inliers, mono_link_weighted, mono_link_min_confidence
) -> Link | None:
    """The encoder's link: the plain median log ratio over every pixel both depths have (the default,
    as before), or with ``mono_link_weighted`` the confidence-weighted one of :func:`estimate_link`.
    Its ``sigma``: the robust spread over the root of the independent pixels, either way. None: fewer
    than ``min_inliers`` pixels."""
    if cfg.mono_link_weighted:
        return estimate_link(sd, z0, sc, c0, cfg.mono_link_min_confidence, min_pixels=cfg.min_inliers)
    both = np.isfinite(z0) & np.isfinite(sd) & (z0 > 0)
    if both.sum() < cfg.min_inliers:
        return None
    x = np.log(sd[both]) - np.log(z0[both])
    m = float(np.median(x))
    spread = 1.4826 * float(np.median(np.abs(x - m)))
    return Link(m, spread / float(np.sqrt(min(len(x), INDEPENDENT_PIXELS))), len(x), spread)
