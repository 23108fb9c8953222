"""Exception hierarchy shared by :mod:`noise` and :mod:`scenesim`.

Every error raised for bad input names the parameter, the bad value and what is
allowed, and is raised before any work starts (and before any file is opened).
"""

__all__ = ["ScenesimError", "ParameterError", "FileFormatError"]


class ScenesimError(Exception):
    """Base class of every error raised on purpose by this project."""


class ParameterError(ScenesimError, ValueError):
    """A parameter has a value outside what is allowed."""


class FileFormatError(ScenesimError, ValueError):
    """An input file is missing, unreadable, or does not have the expected layout."""
