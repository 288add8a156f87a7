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
  clipped to them, changing by at most ``truth.nav_rate_per_s`` of the bound per second
  (``truth.nav_model`` realistic); or, ``truth.nav_model`` filter, what a filter outputs between
  measurement updates: constant, and a new draw within the bound (a third of it per axis, clipped
  to the unit ball) at each update, every ``truth.nav_update_s``. The chief's own state is
  measured exactly (its absolute navigation error is common to both spacecraft and not
  modelled).

``truth.draw`` corner pins every per-run draw to a corner of the declared bounds
(:class:`~cikan_ros.config.Corner`, docs/robustness.md "Corners, the filter navigation model and
between-sample checks"), at ``truth.corner_fraction`` of them: b = +-b_max; a rotation by
+-theta_max about one axis of the chief's VNB frame at the epoch (along: its velocity, normal: the
orbit normal, radial: the third, in plane); a constant |d| = d_max along +-the chief's velocity at
each step (the along-track push, as differential drag acts, which drifts the deputy along the
approach corridor); a navigation error of exactly b_p(r), b_v(r) at the true range r along +-the
line of sight from the chief to the deputy (the direction that changes the measured range and
range rate, what the cone, the approach speed and the docking test are judged on), moving toward
it by at most the declared rate (``truth.nav_rate_per_s``; near the chief, where the line of sight
turns faster, the error lags it inside its bound); under the filter model its sign flips at every
update (the largest jump, 2 b).

Every bound is the configured one times ``truth.scale``; the Gauss-Markov processes have a
standard deviation of a third of their bound per axis, so the clip acts rarely and the bound
holds always. With every bound 0 and two-body gravity (the ``nominal`` truth) each step is the
nominal model's, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .config import CORNER_AXES, Config, Corner, parse_corner
from .dynamics import Plant
from .orbit import KeplerOrbit, vnb_frame

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
        #: Index of the navigation update in force at each sample (the filter model's draw).
        self.nav_update = np.array([tc.nav_update_index(t) for t in times])
        #: The corner flown (``truth.draw`` corner), else None.
        self.corner: Corner | None = None
        #: Navigation error per sample as a signed fraction of its bound along the line of sight
        #: (corners), else None; ``nav_pos``, ``nav_vel``: the error per sample in the unit ball
        #: (random draws), else None. :meth:`nav_error` reads either.
        self.nav_sign: NDArray | None = None
        self.nav_pos: NDArray | None = None
        self.nav_vel: NDArray | None = None
        if tc.draw == "corner":
            self._pin_corner(parse_corner(tc.corner))
            return
        rng = np.random.default_rng([TRUTH_STREAM, 0 if seed is None else 1, abs(int(seed or 0))])
        self.bias = tc.bound("thrust_bias_max") * rng.uniform(-1.0, 1.0)
        axis = rng.normal(size=3)
        self.pointing_axis = axis / np.linalg.norm(axis)
        self.pointing_rad = math.radians(tc.bound("thrust_pointing_max_deg")) * rng.uniform(0.0, 1.0)
        self.thrust_matrix = (1.0 + self.bias) * rotation(self.pointing_axis, self.pointing_rad)
        self.disturbance = tc.bound("disturbance_max_kmps2") * gauss_markov(
            rng, n, self.period, tc.disturbance_correlation_s)
        if tc.nav_model == "realistic":
            step = tc.nav_rate_per_s * self.period
            self.nav_pos = gauss_markov(rng, n, self.period, tc.nav_correlation_s, step)
            self.nav_vel = gauss_markov(rng, n, self.period, tc.nav_correlation_s, step)
        else:
            draws = rng.normal(0.0, 1.0 / 3.0, (2, int(self.nav_update[-1]) + 1, 3))
            draws /= np.maximum(1.0, np.linalg.norm(draws, axis=-1, keepdims=True))
            self.nav_pos, self.nav_vel = draws[0][self.nav_update], draws[1][self.nav_update]

    def _pin_corner(self, corner: Corner) -> None:
        """Pin every per-run draw to ``corner`` at ``truth.corner_fraction`` of the bounds
        (module docstring)."""
        tc = self.tc
        f = tc.corner_fraction
        self.corner = corner
        self.bias = corner.bias * f * tc.bound("thrust_bias_max")
        self.pointing_axis = corner.rotation * vnb_frame(self.chief[0])[CORNER_AXES.index(corner.axis)]
        self.pointing_rad = f * math.radians(tc.bound("thrust_pointing_max_deg"))
        self.thrust_matrix = (1.0 + self.bias) * rotation(self.pointing_axis, self.pointing_rad)
        along = self.chief[:, 3:] / np.linalg.norm(self.chief[:, 3:], axis=1, keepdims=True)
        self.disturbance = corner.disturbance * f * tc.bound("disturbance_max_kmps2") * along
        flips = 1.0 if tc.nav_model == "realistic" else np.where(self.nav_update % 2 == 0, 1.0, -1.0)
        self.nav_sign = corner.nav * f * np.broadcast_to(flips, self.nav_update.shape)
        #: The rate-limited corner's error per step evaluated (:meth:`_rate_limited`).
        self._corner_units: dict[int, NDArray] = {}

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
        e_p, e_v = self._nav_error(k, x_d, rng, bp, bv)
        return np.concatenate([x_d[:3] + e_p, x_d[3:] + e_v]), cov

    def nav_error(self, k: int, x_d: NDArray) -> tuple[NDArray, NDArray]:
        """The navigation error (km, km/s; ECI) on the true deputy x_d at t_k: measured - true."""
        rng = float(np.linalg.norm(x_d[:3] - self.chief[k, :3]))
        return self._nav_error(k, x_d, rng, *self.nav_bounds(rng))

    def _nav_error(self, k: int, x_d: NDArray, rng: float, bp: float, bv: float
                   ) -> tuple[NDArray, NDArray]:
        if self.nav_sign is None:
            return bp * self.nav_pos[k], bv * self.nav_vel[k]
        # a corner: along the line of sight (the chief's velocity if the deputy sits on the chief)
        rel = x_d[:3] - self.chief[k, :3]
        los = rel / rng if rng > 0.0 else self.chief[k, 3:] / np.linalg.norm(self.chief[k, 3:])
        unit = self.nav_sign[k] * los
        if self.tc.nav_model == "realistic":
            unit = self._rate_limited(k, unit)
        return bp * unit, bv * unit

    def _rate_limited(self, k: int, target: NDArray) -> NDArray:
        """A corner's navigation error as a fraction of its bound (in the unit ball) under the
        rate-limited model: toward ``target`` (the line of sight at the bound) from the previous
        step's by at most ``truth.nav_rate_per_s`` T_c, as the declared model allows; on the bound
        where the line of sight turns slowly (every step but those near the chief), and pinned
        there at a step whose predecessor was not evaluated (the first)."""
        prev = self._corner_units.get(k - 1)
        out = target
        if prev is not None:
            step = self.tc.nav_rate_per_s * self.period
            gap = float(np.linalg.norm(target - prev))
            if gap > step:
                out = prev + (target - prev) * (step / gap)
        self._corner_units[k] = out
        return out

    def measure_chief(self, k: int) -> NDArray:
        """The chief state as navigation gives it at t_k (exact; module docstring)."""
        return self.chief[k]

    def applied_thrust(self, u: NDArray) -> NDArray:
        """The acceleration (km/s^2) the thrusters apply for the command u: (1 + b) R u."""
        if self.nominal:
            return u
        return self.thrust_matrix @ u

    def deputy_path(self, k: int, x_d: NDArray, u_applied: NDArray) -> NDArray:
        """The true deputy (S + 1, 6) at the plant's substeps t_k + j T_c / S, j = 0 .. S
        (S = ``mission.plant_substeps``) from x_d at t_k under the applied thrust and the
        disturbance; the last row is the deputy at t_{k+1}."""
        if self.nominal:
            return self.plant.path(x_d, u_applied, self.period)
        return self.plant.path(x_d, u_applied + self.disturbance[k], self.period)

    def chief_path(self, k: int) -> NDArray:
        """The true chief (S + 1, 6) at the plant's substeps of control period k (as
        :meth:`deputy_path`): the Kepler orbit there (two-body), or its integration's own
        substeps from t_k (J2; the last row is ``chief[k + 1]``, bit for bit)."""
        if self.tc.effective_gravity == "two-body":
            s = self.plant.substeps
            return self.orbit.state(np.array([(k + j / s) * self.period for j in range(s + 1)]))
        return self.plant.path(self.chief[k], np.zeros(3), self.period)
