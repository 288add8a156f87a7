"""Paired ratio of sums and its standard error (golden, reference, properties)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cikan_ros.paired import paired_ratio


def test_with_unit_denominators_it_is_the_standard_error_of_the_mean() -> None:
    """b_i = 1: R = mean(a) = 2, e = (-1, 0, 1), SE = sqrt(3/2 · 2) / 3 = s/√n = 1/√3."""
    p = paired_ratio([1.0, 2.0, 3.0], [1.0, 1.0, 1.0])
    assert p.ratio == 2.0
    assert p.se == pytest.approx(1.0 / math.sqrt(3.0), rel=1e-15)
    assert p.n == 3


def test_proportional_pairs_have_no_sampling_error() -> None:
    """a_i = 1.02 b_i for every pair: R = 1.02 whatever the spread of b, SE = 0."""
    b = [0.8, 1.5, 2.6, 4.6]
    p = paired_ratio([1.02 * x for x in b], b)
    assert p.ratio == pytest.approx(1.02, rel=1e-15)
    assert p.se == pytest.approx(0.0, abs=1e-15)


def test_it_agrees_with_a_bootstrap_of_the_ratio() -> None:
    """Independent reference: the standard deviation of R over 20 000 bootstrap resamples of 100
    heavy-tailed pairs (ΔV-like: b lognormal, a = b (1 + noise with a tail))."""
    rng = np.random.default_rng(7)
    b = rng.lognormal(0.5, 0.4, 100)
    a = b * (1.0 + 0.1 * rng.standard_t(3, 100))
    p = paired_ratio(a.tolist(), b.tolist())
    idx = rng.integers(0, 100, (20_000, 100))
    boot = a[idx].sum(axis=1) / b[idx].sum(axis=1)
    assert p.ratio == pytest.approx(a.sum() / b.sum(), rel=1e-14)
    assert p.se == pytest.approx(boot.std(), rel=0.08)


def test_one_pair_has_no_standard_error_and_bad_input_is_named() -> None:
    assert paired_ratio([2.0], [1.0]).se is None
    with pytest.raises(ValueError, match="differ in length"):
        paired_ratio([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="nonzero denominator"):
        paired_ratio([], [])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.1, 10.0), st.floats(0.1, 10.0)), min_size=2, max_size=40),
       st.floats(0.01, 100.0))
def test_scaling_both_samples_leaves_ratio_and_error_unchanged(pairs, k) -> None:
    a, b = zip(*pairs)
    p, q = paired_ratio(a, b), paired_ratio([k * x for x in a], [k * y for y in b])
    assert q.ratio == pytest.approx(p.ratio, rel=1e-12)
    assert q.se == pytest.approx(p.se, rel=1e-9, abs=1e-12)
    assert p.se >= 0.0
