"""Root of the library's exceptions.

Every module raises its own subclass of :class:`GsslamError` with a message a user can act on;
the CLI prints such errors as one line and exits non-zero.
"""


class GsslamError(Exception):
    """Base class of every error gsslam raises on purpose (bad input, missing files, ...)."""
