"""The one exception type of the ``factors`` package."""


class FactorInputError(ValueError):
    """A factor was constructed from measurements it cannot use (NaN/inf, too few, wrong shapes)."""
