"""Exceptions with messages meant for users: the CLI prints them without a traceback."""


class CikanError(Exception):
    """Base class of every error the project raises on purpose (``cikan``: exit code 2, bad input)."""

    #: Exit code of ``cikan`` when this error ends a command.
    exit_code = 2


class MissionError(CikanError):
    """A mission that ran and failed: a node ended abnormally, the bag lost messages (exit code 1)."""

    exit_code = 1


class ConfigError(CikanError, ValueError):
    """A configuration file or value is missing, malformed or out of range."""


class StateError(CikanError, ValueError):
    """A spacecraft state or time is non-finite or physically degenerate."""


class NoFeasibleShiftError(CikanError):
    """No time shift in the search window satisfies the constraints (initial condition rejected)."""
