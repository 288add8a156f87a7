"""ExpHyperbolicLR (Kim et al. 2024, "HyperbolicLR"), written in-house from its formula (SPEC §7).

η(x) = η₀ (η₀/η_inf)^(f(x) - f(0)),  f(x) = sqrt((N - x)/U · (2 - (N + x)/U)),
x the epoch (clamped to N), N the planned epochs, U >= N the upper bound. With U = N, f(0) = 1 and
f(N) = 0, so η(N) = η_inf exactly; past N the rate stays at η(N) (no square root of a negative).
"""

from __future__ import annotations

import math

from torch.optim import Optimizer
from torch.optim.lr_scheduler import LRScheduler


def hyperbolic_f(x: float, n: int, u: int) -> float:
    """f(x) = sqrt((N - x)/U · (2 - (N + x)/U)) with x clamped to [0, N]."""
    x = min(max(float(x), 0.0), float(n))
    return math.sqrt(max((n - x) / u * (2.0 - (n + x) / u), 0.0))


def exp_hyperbolic_lr(x: float, lr0: float, lr_inf: float, n: int, u: int) -> float:
    """η(x) of ExpHyperbolicLR (learning rate at epoch x)."""
    return lr0 * (lr0 / lr_inf) ** (hyperbolic_f(x, n, u) - hyperbolic_f(0.0, n, u))


class ExpHyperbolicLR(LRScheduler):
    """Per-epoch ExpHyperbolicLR for every parameter group (η₀ = the group's initial lr).

    Args: optimizer, ``max_iter`` N (epochs planned), ``upper_bound`` U >= N, ``infimum_lr`` η_inf.
    """

    def __init__(self, optimizer: Optimizer, max_iter: int, upper_bound: int, infimum_lr: float,
                 last_epoch: int = -1) -> None:
        if max_iter < 1:
            raise ValueError(f"max_iter must be >= 1, got {max_iter}")
        if upper_bound < max_iter:
            raise ValueError(f"upper_bound U = {upper_bound} must be >= max_iter N = {max_iter}")
        if not infimum_lr > 0:
            raise ValueError(f"infimum_lr must be > 0, got {infimum_lr}")
        self.max_iter, self.upper_bound, self.infimum_lr = max_iter, upper_bound, infimum_lr
        super().__init__(optimizer, last_epoch)

    def get_lr(self) -> list[float]:
        return [exp_hyperbolic_lr(self.last_epoch, base, self.infimum_lr, self.max_iter,
                                  self.upper_bound) for base in self.base_lrs]

    def _get_closed_form_lr(self) -> list[float]:
        return self.get_lr()
