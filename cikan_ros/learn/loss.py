"""The paper's constraint-informed log loss (SPEC §7, paper eq. log_aug_msrelu).

L = mean((y - ŷ)²) + θ_c · mean(ReLU(y - ŷ)²), y = ln|τ*| (s). ŷ < y means a predicted shift
smaller in magnitude than the label: possibly infeasible, so it is penalised (1 + θ_c) times.
"""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor


def cinn_log_loss(pred: Tensor, target: Tensor, theta_c: float = 1.0) -> Tensor:
    """L(pred, target) for predicted and labelled ln|τ| (B,) -> scalar."""
    err = target - pred
    return (err * err).mean() + theta_c * (torch.relu(err) ** 2).mean()


def cinn_log_loss_np(pred: NDArray, target: NDArray, theta_c: float = 1.0) -> float:
    """The same loss in float64 numpy, for reporting over a whole split."""
    err = np.asarray(target, dtype=np.float64) - np.asarray(pred, dtype=np.float64)
    return float(np.mean(err * err) + theta_c * np.mean(np.maximum(err, 0.0) ** 2))
