"""ExpHyperbolicLR and the constraint-informed log loss against hand computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cikan_ros.learn.loss import cinn_log_loss, cinn_log_loss_np
from cikan_ros.learn.schedule import ExpHyperbolicLR, exp_hyperbolic_lr


def _opt(lr: float) -> torch.optim.Optimizer:
    return torch.optim.AdamW([torch.nn.Parameter(torch.zeros(1))], lr=lr)


def test_reaches_infimum_at_n_when_u_equals_n_and_never_errors_past_n() -> None:
    n, lr0, lr_inf = 12, 1e-2, 1e-4
    opt = _opt(lr0)
    sched = ExpHyperbolicLR(opt, max_iter=n, upper_bound=n, infimum_lr=lr_inf)
    lrs = [opt.param_groups[0]["lr"]]
    for _ in range(3 * n):
        opt.step()
        sched.step()
        lrs.append(opt.param_groups[0]["lr"])
    assert lrs[0] == pytest.approx(lr0, rel=1e-12)
    assert lrs[n] == pytest.approx(lr_inf, rel=1e-12)
    assert all(lr == pytest.approx(lr_inf, rel=1e-12) for lr in lrs[n:])
    assert all(a >= b for a, b in zip(lrs[:n], lrs[1:n + 1]))  # non-increasing


def test_matches_formula_by_hand() -> None:
    n, u, lr0, lr_inf = 10, 15, 1e-3, 1e-5

    def f(x: float) -> float:
        return math.sqrt((n - x) / u * (2 - (n + x) / u))

    for x in (0, 3, 7, 10):
        ref = lr0 * (lr0 / lr_inf) ** (f(x) - f(0))
        assert exp_hyperbolic_lr(x, lr0, lr_inf, n, u) == pytest.approx(ref, rel=1e-12)
    # U > N: the rate at N stays above the infimum; past N it is clamped at eta(N).
    assert exp_hyperbolic_lr(n, lr0, lr_inf, n, u) > lr_inf
    assert exp_hyperbolic_lr(5 * n, lr0, lr_inf, n, u) == exp_hyperbolic_lr(n, lr0, lr_inf, n, u)


def test_rejects_upper_bound_below_n() -> None:
    with pytest.raises(ValueError):
        ExpHyperbolicLR(_opt(1e-3), max_iter=10, upper_bound=5, infimum_lr=1e-5)


def test_loss_hand_computed_batch() -> None:
    pred = [1.0, 2.0, 3.0, -0.5]
    target = [1.5, 1.0, 3.0, 0.5]
    # errors y - y_hat: 0.5, -1, 0, 1 -> squares .25, 1, 0, 1; relu^2: .25, 0, 0, 1
    theta_c = 2.0
    ref = (0.25 + 1 + 0 + 1) / 4 + theta_c * (0.25 + 1) / 4
    got = cinn_log_loss(torch.tensor(pred, dtype=torch.float64), torch.tensor(target, dtype=torch.float64),
                        theta_c)
    assert float(got) == pytest.approx(ref, rel=1e-15)
    assert cinn_log_loss_np(np.array(pred), np.array(target), theta_c) == pytest.approx(ref, rel=1e-15)
    # Under-predicting |tau| (y_hat < y) costs (1 + theta_c) times as much as over-predicting.
    over = cinn_log_loss_np(np.array([1.1]), np.array([1.0]), theta_c)
    under = cinn_log_loss_np(np.array([0.9]), np.array([1.0]), theta_c)
    assert under == pytest.approx((1 + theta_c) * over, rel=1e-12)
