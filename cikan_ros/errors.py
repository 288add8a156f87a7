"""Exceptions with messages meant for users: the CLI prints them without a traceback."""


class CikanError(Exception):
    """Base class of every error the project raises on purpose."""


class ConfigError(CikanError, ValueError):
    """A configuration file or value is missing, malformed or out of range."""


class StateError(CikanError, ValueError):
    """A spacecraft state or time is non-finite or physically degenerate."""


class NoFeasibleShiftError(CikanError):
    """No time shift in the search window satisfies the constraints (initial condition rejected)."""
