"""The truth: the world the simulator flies, separate from the governors' prediction model.

A :class:`Truth` is drawn once per run from the ``truth`` configuration and the run's seed (the
same seed gives the same run, in the offline loop and in sim_node alike):

- gravity: two-body, or two-body + J2 on both spacecraft (``truth.gravity``); the chief is then
  integrated numerically (RK4, ``mission.plant_substeps`` steps per control period) from the
  configured orbit at the epoch, the deputy likewise under its applied thrust;
- thruster execution errors, drawn per run: the applied acceleration is (1 + b) R u with the
  magnitude bias b uniform in [-b_max, b_max] and R a rotation by an angle uniform in
  [0, theta_max] about a random axis (so |applied - commanded| <= eps_u |u|);
- a process disturbance d_k held over each control period: a first-order Gauss-Markov vector
  (correlation ``truth.disturbance_correlation_s``), clipped to |d_k| <= d_max;
- a navigation error on the deputy's state, what a relative-navigation filter outputs: a
  Gauss-Markov vector per position and velocity (correlation ``truth.nav_correlation_s``),
  scaled by the bounds b_p(r) = floor + fraction r (velocity likewise) at the true range r and
  clipped to them, changing by at most ``truth.nav_rate_per_s`` of the bound per second. The chief's own state is measured exactly (its absolute navigation error is
  common to both spacecraft and not modelled).

Every bound is the configured one times ``truth.scale``; the Gauss-Markov processes have a
standard deviation of a third of their bound per axis, so the clip acts rarely and the bound
holds always. With every bound 0 and two-body gravity (the ``nominal`` truth) each step is the
nominal model's, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .config import Config
from .dynamics import Plant
from .orbit import KeplerOrbit

#: Stream of the truth's random numbers (independent of the Monte Carlo start's stream).
TRUTH_STREAM = 0x7472757468


def gauss_markov(rng: np.random.Generator, n: int, dt: float, corr_s: float,
                 max_step: float = math.inf) -> NDArray:
    """n samples (n, 3) of a first-order Gauss-Markov vector with standard deviation 1/3 per
    axis and correlation time corr_s (stationary start), kept in the unit ball and, when
    ``max_step`` is finite, changing by at most ``max_step`` per sample (a smooth process)."""
    phi = math.exp(-dt / corr_s)
    w = rng.normal(0.0, 1.0 / 3.0, (n, 3))
    out = np.empty((n, 3))
    q = math.sqrt(1.0 - phi * phi)
    out[0] = w[0] / max(1.0, float(np.linalg.norm(w[0])))
    for k in range(1, n):
        step = phi * out[k - 1] + q * w[k] - out[k - 1]
        size = float(np.linalg.norm(step))
        if size > max_step:
            step *= max_step / size
        nxt = out[k - 1] + step
        out[k] = nxt / max(1.0, float(np.linalg.norm(nxt)))  # projection: |change| stays bounded
    return out


def rotation(axis: NDArray, angle: float) -> NDArray:
    """Rotation matrix (3, 3) by ``angle`` (rad) about the unit vector ``axis`` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


class Truth:
    """One run's truth (module docstring): the chief's trajectory, the deputy's plant and the
    measured states. ``seed`` None (the nominal start) draws from a stream of its own."""

    def __init__(self, cfg: Config, seed: int | None = None, n_steps: int | None = None) -> None:
        self.config = cfg
        tc = cfg.truth
        self.tc = tc
        self.period = cfg.control.period_s
        self.n_steps = n_steps if n_steps is not None else round(cfg.mission.duration_s / self.period)
        self.nominal = tc.is_nominal
        self.orbit = KeplerOrbit.from_config(cfg.orbit)
        self.plant = Plant(self.orbit.mu, cfg.mission.plant_substeps, gravity=tc.effective_gravity)
        n = self.n_steps + 1
        times = np.array([k * self.period for k in range(n)])
        if tc.effective_gravity == "two-body":
            self.chief = self.orbit.state(times)
        else:
            self.chief = np.empty((n, 6))
            self.chief[0] = self.orbit.state(0.0)
            zero = np.zeros(3)
            for k in range(1, n):
                self.chief[k] = self.plant.step(self.chief[k - 1], zero, self.period)
        rng = np.random.default_rng([TRUTH_STREAM, 0 if seed is None else 1, abs(int(seed or 0))])
        self.bias = tc.bound("thrust_bias_max") * rng.uniform(-1.0, 1.0)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        self.pointing_rad = math.radians(tc.bound("thrust_pointing_max_deg")) * rng.uniform(0.0, 1.0)
        self.thrust_matrix = (1.0 + self.bias) * rotation(axis, self.pointing_rad)
        self.disturbance = tc.bound("disturbance_max_kmps2") * gauss_markov(
            rng, n, self.period, tc.disturbance_correlation_s)
        step = tc.nav_rate_per_s * self.period
        self.nav_pos = gauss_markov(rng, n, self.period, tc.nav_correlation_s, step)
        self.nav_vel = gauss_markov(rng, n, self.period, tc.nav_correlation_s, step)

    def chief_state(self, k: int) -> NDArray:
        """The true chief at t_k (6,), km, km/s, ECI."""
        return self.chief[k]

    def nav_bounds(self, range_km: float) -> tuple[float, float]:
        """The navigation error bounds (km, km/s) at a range (km)."""
        tc = self.tc
        return (tc.bound("nav_pos_floor_km") + tc.bound("nav_pos_range_fraction") * range_km,
                tc.bound("nav_vel_floor_kmps") + tc.bound("nav_vel_range_fraction_per_s") * range_km)

    def measure_deputy(self, k: int, x_d: NDArray) -> tuple[NDArray, NDArray]:
        """The deputy state as navigation gives it at t_k, and its covariance (6, 6) (km^2,
        km^2/s^2: the Gauss-Markov variance, a third of the bound squared per axis)."""
        rng = float(np.linalg.norm(x_d[:3] - self.chief[k, :3]))
        bp, bv = self.nav_bounds(rng)
        cov = np.diag([(bp / 3.0) ** 2] * 3 + [(bv / 3.0) ** 2] * 3)
        if self.nominal:
            return x_d, cov
        return np.concatenate([x_d[:3] + bp * self.nav_pos[k], x_d[3:] + bv * self.nav_vel[k]]), cov

    def measure_chief(self, k: int) -> NDArray:
        """The chief state as navigation gives it at t_k (exact; module docstring)."""
        return self.chief[k]

    def applied_thrust(self, u: NDArray) -> NDArray:
        """The acceleration (km/s^2) the thrusters apply for the command u: (1 + b) R u."""
        if self.nominal:
            return u
        return self.thrust_matrix @ u

    def step_deputy(self, k: int, x_d: NDArray, u_applied: NDArray) -> NDArray:
        """The true deputy at t_{k+1} from x_d at t_k under the applied thrust and the disturbance."""
        if self.nominal:
            return self.plant.step(x_d, u_applied, self.period)
        return self.plant.step(x_d, u_applied + self.disturbance[k], self.period)
