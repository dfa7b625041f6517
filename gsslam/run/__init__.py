"""The runner: run a dataset or a bag, write its outputs, export and view a run folder."""
