"""Paired ratios of sums, with their standard errors: a governor's runs against the conventional
TSG's flown from the same Monte Carlo starts.

Missions are chaotic (SPEC §10): a small change in the τ history can send a run into a slower
approach, so per-run ΔV ratios spread by about ±10 % with tails past +80 %. The ratio of sums
R = Σ a_i / Σ b_i over n paired runs therefore carries a sampling error of 1-2 % at n = 100,
which a comparison against a +2 % bound has to state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence


@dataclass(frozen=True)
class PairedRatio:
    """R = Σ a_i / Σ b_i and its standard error (None for fewer than two pairs)."""

    ratio: float
    se: float | None
    n: int


def paired_ratio(a: Sequence[float], b: Sequence[float]) -> PairedRatio:
    """Ratio of sums of paired samples and its delta-method standard error.

    With R = Σa/Σb and residuals e_i = a_i - R b_i,
    SE(R) = sqrt(n / (n - 1) · Σ e_i²) / Σ b_i  (Cochran, Sampling Techniques, ratio estimator).
    For b_i = 1 this is the standard error of the mean of a, s / √n.
    """
    if len(a) != len(b):
        raise ValueError(f"paired samples differ in length: {len(a)} and {len(b)}")
    n = len(a)
    sb = math.fsum(b)
    if n == 0 or sb == 0.0:
        raise ValueError("a ratio of sums needs at least one pair and a nonzero denominator")
    r = math.fsum(a) / sb
    if n < 2:
        return PairedRatio(r, None, n)
    ss = math.fsum((x - r * y) ** 2 for x, y in zip(a, b))
    return PairedRatio(r, math.sqrt(n / (n - 1) * ss) / abs(sb), n)
