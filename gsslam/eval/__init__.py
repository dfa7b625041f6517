"""Trajectory and image metrics: pure functions returning JSON-able dataclasses.

- :mod:`~gsslam.eval.association` pairs poses of two trajectories by timestamp,
- :mod:`~gsslam.eval.align` fits an Umeyama SE(3)/Sim(3) alignment,
- :mod:`~gsslam.eval.ate` / :mod:`~gsslam.eval.rpe` compute absolute / relative pose errors,
- :mod:`~gsslam.eval.image_metrics` gives PSNR and SSIM,
- :mod:`~gsslam.eval.report` ties them together (files are read by :mod:`gsslam.run.evaluate`).

The trajectory metrics follow evo's definitions (see docs/evaluation.md). No function here modifies
its inputs.
"""

from gsslam.errors import GsslamError


class EvalError(GsslamError):
    """Base of the evaluation errors (bad pairing, too few poses, mismatched images)."""
