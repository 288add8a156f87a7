"""Errors of the learning pipeline (printed by the CLI as one line, no traceback)."""

from __future__ import annotations

from ..errors import CikanError


class ModelFileError(CikanError):
    """A model directory or file is missing, truncated, corrupt or does not match its card."""


class DatasetError(CikanError):
    """A label dataset is missing, malformed, or too small for the requested use."""
