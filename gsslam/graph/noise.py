"""Noise models and sigmas of the SLAM factors, from :class:`gsslam.config.GraphConfig`."""

from __future__ import annotations

import gtsam
import numpy as np

from gsslam.config import GraphConfig


def gauge_prior_sigmas(cfg: GraphConfig) -> np.ndarray:  # [7]
    """Sigmas of the Sim(3) prior on the first submap: rotation, translation AND scale (chart order)."""
    return np.array([cfg.prior_rot_sigma] * 3 + [cfg.prior_trans_sigma] * 3 + [cfg.prior_scale_sigma])


def gauge_prior_noise(cfg: GraphConfig) -> gtsam.noiseModel.Diagonal:
    """Sim(3) prior on the first submap: rotation, translation AND scale fixed (chart order)."""
    return gtsam.noiseModel.Diagonal.Sigmas(gauge_prior_sigmas(cfg))


def flow_kwargs(cfg: GraphConfig) -> dict:
    """Keyword arguments of :func:`gsslam.factors.make_flow_factor` taken from the config."""
    return {
        "sigma_px": cfg.flow_sigma_px,
        "inlier_prior": cfg.flow_inlier_prior,
        "outlier_range_px": cfg.flow_outlier_range_px,
    }


def isam_params(cfg: GraphConfig) -> gtsam.ISAM2Params:
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(cfg.relinearize_threshold)
    params.relinearizeSkip = cfg.relinearize_skip
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(cfg.wildfire_threshold))
    return params
