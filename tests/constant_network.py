"""A learned governor whose network answers one constant shift: the adversary of the keep rule's
tests (tests/test_trust.py) and of the ladder's mirror test (tests/test_scenarios.py)."""

from __future__ import annotations

import math

import numpy as np
import torch

from cikan_ros.learn.arch import Arch, NumpyNet
from cikan_ros.learn.features import features
from cikan_ros.learn.governor import LearnedGovernor
from cikan_ros.learn.models import TimeShiftNet
from cikan_ros.mission import nominal_start
from cikan_ros.tsg import Predictor


def constant_governor(predictor: Predictor, tau_abs: float) -> LearnedGovernor:
    """A network whose output is the constant ln|tau| = ln(tau_abs) (all weights zero)."""
    arch = Arch("relu", 8, 2)
    net = TimeShiftNet(arch)
    x0 = nominal_start(predictor)
    f0 = features(x0, predictor.orbit.state(0.0))
    net.set_normalisation(f0, np.abs(f0) * 0.1 + 1.0, math.log(tau_abs), 1.0)
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
    sd = {k: v.detach().numpy() for k, v in net.state_dict().items()}
    return LearnedGovernor(NumpyNet(arch, sd), predictor, f"constant-{tau_abs:g}")
