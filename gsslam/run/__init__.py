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
