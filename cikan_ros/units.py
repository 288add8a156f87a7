"""Unit conversions at the ROS boundary (SPEC §1): internal km, s; messages SI (m, s, ns stamps).

The offline mission passes states and commands through the same conversions as the ROS graph, so
the governor and the controller see bit-identical numbers in both (the equivalence test relies
on it). Times are whole nanoseconds since the mission epoch; ``ns / 1e9`` is the one conversion
to seconds used on both sides.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

KM = 1000.0  # metres per kilometre


def km_to_m(x: ArrayLike) -> NDArray:
    """km (or km/s, km/s^2) -> m (m/s, m/s^2)."""
    return np.asarray(x, dtype=float) * KM


def m_to_km(x: ArrayLike) -> NDArray:
    """m (or m/s, m/s^2) -> km (km/s, km/s^2)."""
    return np.asarray(x, dtype=float) / KM


def through_si(x: ArrayLike) -> NDArray:
    """What a receiver reads after the value went out in SI: ``m_to_km(km_to_m(x))``."""
    return m_to_km(km_to_m(x))


def seconds_to_ns(t: float) -> int:
    """Seconds -> nearest whole nanosecond."""
    return int(round(float(t) * 1e9))


def ns_to_seconds(ns: int) -> float:
    """Whole nanoseconds -> seconds (exact for whole seconds; the single conversion used everywhere)."""
    return ns / 1e9
