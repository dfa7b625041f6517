"""The runner: run a dataset, write its outputs; batches of runs (:mod:`gsslam.run.batch`)."""
