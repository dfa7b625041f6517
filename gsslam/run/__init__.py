"""The runner, the command line's only door into the library.

- :mod:`~gsslam.run.sequence`: open a dataset, feed it to :class:`gsslam.slam.pipeline.Pipeline`,
  write the outputs (:func:`run_sequence`, :func:`run_dataset`, :class:`RunResult`).
- :mod:`~gsslam.run.outputs`: the files of a run (trajectories, metrics, plots, map outputs).
- :mod:`~gsslam.run.render`: re-render a saved map along a saved trajectory (``gsslam render``).
- :mod:`~gsslam.run.evaluate`: evaluate two trajectory files (``gsslam eval``).
- :mod:`~gsslam.run.keyframes`: the keyframe images a run keeps (``keyframes/<timestamp>.jpg``).
- :mod:`~gsslam.run.export`: a run as COLMAP / nerfstudio / INRIA files (``gsslam export``).
- :mod:`~gsslam.run.batch`: many sequences x configurations (``gsslam batch``), with
  :mod:`~gsslam.run.manifest` (what to run), :mod:`~gsslam.run.run_metrics` (one run folder -> one row)
  and :mod:`~gsslam.run.results` (the table, pure); built-in suites in ``run/suites/``.
"""

import sys
import types
from pathlib import Path


class _CallablePackage(types.ModuleType):
    """``gsslam.run(path, ...)``: the package itself runs a dataset folder (see :meth:`__call__`)."""

    def __call__(
        self,
        path,
        dataset: str = "tum",
        out="gsslam_out",
        config=None,
        mode: str | None = None,
        overrides=(),
        max_frames: int | None = None,
        **dataset_kwargs,
    ):
        """Run the dataset folder ``path`` (loader ``dataset``) and write the outputs to ``out``.

        ``config``: a YAML path or None, with dotted ``overrides`` and ``mode``. Returns the
        :class:`~gsslam.run.sequence.RunResult` (``.metrics``: what ``metrics.json`` holds).
        """
        from gsslam.config import load_config
        from gsslam.run.sequence import run_sequence

        cfg = load_config(config, list(overrides), mode=mode)
        return run_sequence(Path(path), dataset, cfg, Path(out), max_frames, False, **dataset_kwargs)


sys.modules[__name__].__class__ = _CallablePackage
