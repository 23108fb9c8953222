"""Exception hierarchy shared by :mod:`noise` and :mod:`scenesim`.

Every error raised for bad input names the parameter, the bad value and what is
allowed, and is raised before any work starts (and before any file is opened).
"""

__all__ = ["ScenesimError", "ParameterError", "ParameterTypeError", "FileFormatError",
           "OutputError", "HelperProcessError", "ScenesimWarning"]


class ScenesimError(Exception):
    """Base class of every error raised on purpose by this project."""


class ParameterError(ScenesimError, ValueError):
    """A parameter has a value outside what is allowed."""


class ParameterTypeError(ParameterError, TypeError):
    """A parameter has the wrong type (a string where a number or an array is
    expected, a list where a ``Detector`` is expected, ``None``, ...).

    A :class:`ParameterError` (so a ``ValueError``) and a ``TypeError``: code that
    catches either keeps working.
    """


class FileFormatError(ScenesimError, ValueError):
    """An input file is missing, unreadable, or does not have the expected layout."""


class OutputError(ScenesimError, OSError):
    """An output file could not be written (disk full, file-size limit, I/O error).

    Raised while writing, after the temporary file has been removed; the message names
    the output and the operating system's reason.  ``errno`` is the original error's.
    """

    def __init__(self, message, errno=None):
        super().__init__(message)
        self.errno = errno


class HelperProcessError(ScenesimError, RuntimeError):
    """A helper process of the run (the forked 1/f producer) failed or was killed.

    The message says what happened (its traceback when it raised, or that it exited
    without a result, e.g. after SIGKILL); the run stops and leaves no partial output.
    """


class ScenesimWarning(UserWarning):
    """Base class of the warnings this project issues on purpose: a run that works
    but probably not as its user meant (the commands print them as one line,
    ``'<command>: warning: <message>'``)."""
