"""Algorithm 1 (SPEC §8): the fallback makes any network safe; decisions follow the pseudo-code."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cikan_ros.governor import (PATH_BISECT, PATH_NN, PATH_NN_BISECT, PATH_VERIFY_ZERO, PATH_ZERO)
from cikan_ros.learn.arch import Arch, NumpyNet
from cikan_ros.learn.features import features, features_one
from cikan_ros.learn.governor import LearnedGovernor, nn_accept_rate
from cikan_ros.learn.models import TimeShiftNet
from cikan_ros.mission import nominal_start, run_mission, sample_start
from cikan_ros.tsg import quantise_shift


def _governor(predictor, arch: Arch, seed: int, target_mean: float, target_std: float,
              zero_weights: bool = False) -> LearnedGovernor:
    torch.manual_seed(seed)
    net = TimeShiftNet(arch)
    x0 = nominal_start(predictor)
    f0 = features(x0, predictor.orbit.state(0.0))
    net.set_normalisation(f0, np.abs(f0) * 0.1 + 1.0, target_mean, target_std)
    if zero_weights:
        with torch.no_grad():
            for p in net.parameters():
                p.zero_()
    sd = {k: v.detach().numpy() for k, v in net.state_dict().items()}
    return LearnedGovernor(NumpyNet(arch, sd), predictor, "test")


def _assert_safe_success(res) -> None:
    m = res.metrics()
    assert m["violations"] == 0
    assert m["success"], m


def test_random_weight_networks_never_violate(predictor) -> None:
    """Random KANs on the nominal and a Monte Carlo start: zero violations and |tau| never grows.

    Docking is not asserted here: a random network whose output saturates at a constant shift
    that is feasible gets it accepted at every update and can hold tau there (measured: 1 of 6
    runs, stuck at -0.27 s). Algorithm 1 promises safety, not progress, for any network; the
    fallback-driven cases below do dock."""
    paths: set[str] = set()
    docked = 0
    for seed in (5, 6, 7):
        gov = _governor(predictor, Arch("cikan", 8, 3, grid=5), seed=seed, target_mean=0.0,
                        target_std=3.0)
        for x0 in (nominal_start(predictor), sample_start(predictor, 2)):
            res = run_mission(gov, x0)
            m = res.metrics()
            assert m["violations"] == 0, m
            assert np.all(np.diff(res.tau) >= 0.0) and res.tau[-1] <= 0.0
            docked += m["success"]
            paths |= {r.path for r in res.updates}
    assert paths <= {PATH_NN, PATH_NN_BISECT, PATH_BISECT, PATH_VERIFY_ZERO, PATH_ZERO}
    assert {PATH_NN, PATH_NN_BISECT, PATH_BISECT} <= paths
    assert docked >= 4   # measured 5 of 6


@pytest.mark.parametrize("log_tau,expected", [(math.log(1e-4), PATH_NN_BISECT),
                                              (math.log(1e6), PATH_BISECT)])
def test_constant_wrong_networks_dock_safely(predictor, log_tau: float, expected: str) -> None:
    """Always too close to 0 (|tau| = 1e-4 s), or far outside [tau_prev, 0] (1e6 s)."""
    gov = _governor(predictor, Arch("relu", 8, 2), seed=0, target_mean=log_tau, target_std=1.0,
                    zero_weights=True)
    res = run_mission(gov, sample_start(predictor, 3))
    _assert_safe_success(res)
    active = [r.path for r in res.updates if r.path != PATH_ZERO]
    assert active and active.count(expected) >= len(active) - 1   # the last may snap to zero
    assert nn_accept_rate(res.updates) == 0.0


def test_decisions_follow_algorithm_1(predictor) -> None:
    """Replays the pseudo-code with independent predictor calls on recorded update states."""
    conv = run_mission(_governor(predictor, Arch("relu", 8, 2), 0, 0.0, 1.0, zero_weights=True),
                       nominal_start(predictor))
    tc = predictor.config.control.period_s
    states = [(conv.x_d[int(round(t / tc))], conv.x_c[int(round(t / tc))], t, conv.tau[int(round(t / tc)) - 1])
              for t in conv.update_t if conv.tau[int(round(t / tc)) - 1] < 0][:6]
    assert states
    snap = predictor.config.tsg.zero_snap_s
    for gov_seed in (1, 2, 3):
        gov = _governor(predictor, Arch("gelu", 16, 3), gov_seed, math.log(3.0), 1.0)
        for x_d, x_c, t, tau_prev in states:
            rec = gov.update(x_d, x_c, t, tau_prev)
            feat = features_one(x_d, x_c, "vnb", np.empty(12))
            tau_c = quantise_shift(-math.exp(gov.net.forward_one(gov.net.normalise(feat))))
            if tau_prev <= tau_c <= 0 and predictor.verify(x_d, t, tau_c):
                tau, path = tau_c, PATH_NN
            elif tau_prev <= tau_c <= 0:
                tau, path = predictor.bisect(x_d, t, tau_prev, tau_c)[0], PATH_NN_BISECT
            else:
                tau, path = predictor.bisect(x_d, t, tau_prev, 0.0)[0], PATH_BISECT
            if tau < 0 and -tau <= snap and predictor.verify(x_d, t, 0.0):
                tau, path = 0.0, PATH_VERIFY_ZERO
            assert (rec.tau_s, rec.path) == (tau, path)
            assert rec.tau_s == quantise_shift(rec.tau_s)
            assert rec.tau_s == tau_prev or predictor.verify(x_d, t, rec.tau_s)


def test_zero_shortcut_skips_the_network(predictor) -> None:
    gov = _governor(predictor, Arch("relu", 8, 2), 0, 0.0, 1.0)
    x0 = nominal_start(predictor)
    rec = gov.update(x0, predictor.orbit.state(0.0), 0.0, 0.0)
    assert (rec.tau_s, rec.path, rec.verify_calls) == (0.0, PATH_ZERO, 0)


def test_non_finite_network_output_falls_back_to_bisection(predictor) -> None:
    gov = _governor(predictor, Arch("relu", 8, 2), 0, 0.0, 1.0)
    gov.net.target_mean = math.nan
    x0 = nominal_start(predictor)
    tau0 = predictor.initial_shift(x0, 0.0)[0]
    rec = gov.update(x0, predictor.orbit.state(0.0), 0.0, tau0)
    assert rec.path in (PATH_BISECT, PATH_VERIFY_ZERO)
    assert rec.tau_s == tau0 or predictor.verify(x0, 0.0, rec.tau_s)


def test_single_sample_features_equal_batch_features(predictor) -> None:
    rng = np.random.default_rng(0)
    x_c = predictor.orbit.state(np.linspace(0, 9000, 7))
    x_d = x_c + np.concatenate([rng.normal(0, 20, (7, 3)), rng.normal(0, 0.01, (7, 3))], axis=1)
    for kind in ("vnb", "eci"):
        batch = features(x_d, x_c, kind)
        one = np.array([features_one(a, b, kind, np.empty(12)) for a, b in zip(x_d, x_c)])
        np.testing.assert_allclose(one, batch, rtol=1e-13, atol=1e-9)
