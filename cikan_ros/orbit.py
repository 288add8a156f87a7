"""Two-body orbits: classical elements <-> Cartesian, analytic Kepler propagation, VNB and LVLH
frames.

Frames: Earth-centred inertial (ECI). Units: km, s, km/s, radians unless a name says ``deg``.
The compiled kernels (``*_kernel``) take an orbit as the packed float64 array of
:attr:`KeplerOrbit.params` so that predictions (``cikan_ros.tsg``) call them without Python
overhead; the public functions wrap them for any number of epochs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import OrbitConfig
from .errors import StateError

# Layout of KeplerOrbit.params (the packed form used by compiled kernels).
P_A, P_E, P_MU, P_N, P_M0 = 0, 1, 2, 3, 4
P_PVEC = slice(5, 8)   # unit vector to periapsis (ECI)
P_QVEC = slice(8, 11)  # unit vector 90 deg ahead of periapsis in the orbit plane (ECI)
P_S1E, P_SQMUA = 11, 12  # sqrt(1 - e^2), sqrt(mu a): precomputed for the kernels
N_PARAMS = 13


@nb.njit(cache=True, error_model="numpy", inline="always")
def wrap_anomaly_kernel(angle: float) -> float:
    """``(angle + pi) % (2 pi) - pi``: the angle wrapped to [-pi, pi) (rad), bit for bit as that
    expression, without the library's fmod for angles in [-pi, 3 pi) (every mean anomaly of a
    mission of a few revolutions from periapsis): there the remainder is the sum itself or the
    sum minus 2 pi, which is exact (Sterbenz: 2 pi <= b < 4 pi), as fmod's result is. On
    Verify's virtual target (a Kepler solve per sample) this and the revolution test of
    :func:`state_warm_kernel` took ~25 ns off ~90 (measured)."""
    two_pi = 2.0 * math.pi
    b = angle + math.pi
    if 0.0 <= b < two_pi:
        r = b
    elif two_pi <= b < 2.0 * two_pi:
        r = b - two_pi
    else:
        r = b % two_pi
    return r - math.pi


@nb.njit(cache=True, error_model="numpy")
def _kepler_newton(m: float, e: float, big_e: float) -> float:
    """Newton's method on E - e sin E = m from the guess ``big_e``.

    Stops after a step below 1e-8 rad: Newton's error after a step of size d is at most
    d^2 e / (2 (1 - e)) (< 1.5e-16 rad for e <= 0.74 here), so that step already lands on the root
    to machine precision and one more iteration would only confirm it.
    """
    for _ in range(50):
        step = (big_e - e * math.sin(big_e) - m) / (1.0 - e * math.cos(big_e))
        big_e -= step
        if abs(step) < 1e-8:
            break
    return big_e


@nb.njit(cache=True, error_model="numpy")
def eccentric_anomaly_kernel(mean_anomaly: float, e: float) -> float:
    """Solve Kepler's equation M = E - e sin E by Newton's method (elliptic, 0 <= e < 1).

    M is wrapped to [-pi, pi); the returned E lies in the same revolution as the wrapped M.
    """
    m = wrap_anomaly_kernel(mean_anomaly)
    # Starting guess of Danby (1987): converges for every M at e < 1.
    return _kepler_newton(m, e, m + 0.85 * e * (1.0 if math.sin(m) >= 0.0 else -1.0))


@nb.njit(cache=True, error_model="numpy")
def state_from_anomaly_kernel(orb: NDArray, big_e: float, out: NDArray, want_nu: bool = True) -> float:
    """Write the state [r; v] at eccentric anomaly E into ``out[0:6]``; return nu in [0, 2 pi)
    (or 0 without computing it when ``want_nu`` is False)."""
    return _perifocal_state(orb, math.cos(big_e), math.sin(big_e), out, want_nu)


@nb.njit(cache=True, error_model="numpy", inline="always")
def _perifocal_state(orb: NDArray, ce: float, se: float, out: NDArray, want_nu: bool) -> float:
    """:func:`state_from_anomaly_kernel` from cos E and sin E."""
    a = orb[P_A]
    e = orb[P_E]
    s1e = orb[P_S1E]
    x = a * (ce - e)          # perifocal position
    y = a * s1e * se
    r = a * (1.0 - e * ce)
    k = orb[P_SQMUA] / r
    vx = -k * se              # perifocal velocity
    vy = k * s1e * ce
    for i in range(3):
        p = orb[5 + i]
        q = orb[8 + i]
        out[i] = x * p + y * q
        out[3 + i] = vx * p + vy * q
    if not want_nu:
        return 0.0
    nu = math.atan2(y, x)     # the true anomaly is the polar angle of the perifocal position
    if nu < 0.0:
        nu += 2.0 * math.pi
    return nu


@nb.njit(cache=True, error_model="numpy")
def state_kernel(orb: NDArray, t: float, out: NDArray) -> float:
    """Write the state [r; v] at time t (s since epoch) into ``out[0:6]``; return the true anomaly.

    The true anomaly is in [0, 2 pi).
    """
    return state_from_anomaly_kernel(orb, eccentric_anomaly_kernel(orb[P_M0] + orb[P_N] * t, orb[P_E]), out)


@nb.njit(cache=True, error_model="numpy")
def state_warm_kernel(orb: NDArray, t: float, e_prev: float, s_prev: float, c_prev: float,
                      advance: float, out: NDArray, want_nu: bool = True) -> tuple[float, float, float, float]:
    """:func:`state_kernel` with Newton started from the previous sample's anomaly advanced by
    ``advance`` (n dt / (1 - e cos E) for a sample dt earlier), given s_prev = sin E_prev and
    c_prev = cos E_prev; returns (nu, E, sin E, cos E) for the next sample. Sequential
    predictions (the rollout's virtual target) use it: 1-2 Newton iterations instead of 4-6.

    The sine and cosine of the guess and of each Newton iterate are turned from the previous
    ones by the angle-sum formulas (:func:`_rotated`) rather than computed: a rollout's ~220 ns
    a sample drops by ~35 ns (measured). Each turn rounds, so along a chain sin E and cos E drift
    from the library's: after 10,000 samples of 10 s by at most 6e-13, the state by 1.3e-13 of
    |r| (tests/test_orbit.py; 3 micrometres on the paper's orbit). A rollout starts its chain
    from a computed anomaly."""
    e = orb[P_E]
    two_pi = 2.0 * math.pi
    m = wrap_anomaly_kernel(orb[P_M0] + orb[P_N] * t)
    big_e = e_prev + advance
    if abs(advance) <= ROTATE_MAX:
        se, ce = _rotated(s_prev, c_prev, advance)
    else:
        se = math.sin(big_e)
        ce = math.cos(big_e)
    d = big_e - m
    if not -3.0 < d < 3.0:  # |d| < 3 < pi: the floor is 0, E unchanged; the division skipped
        big_e -= two_pi * math.floor(d / two_pi + 0.5)  # same revolution as m
    for _ in range(50):   # _kepler_newton, turning sin E and cos E with each step
        step = (big_e - e * se - m) / (1.0 - e * ce)
        big_e -= step
        if abs(step) <= ROTATE_MAX:
            se, ce = _rotated(se, ce, -step)
        else:
            se = math.sin(big_e)
            ce = math.cos(big_e)
        if abs(step) < 1e-8:
            break
    return _perifocal_state(orb, ce, se, out, want_nu), big_e, se, ce


#: Largest angle (rad) :func:`_rotated` turns by: its series' first omitted terms, d^8 / 8! and
#: d^9 / 9!, are below 3e-21 there, far under half an ulp of sin and cos.
ROTATE_MAX = 1e-2


@nb.njit(cache=True, error_model="numpy", inline="always")
def _rotated(s: float, c: float, d: float) -> tuple[float, float]:
    """(sin(x + d), cos(x + d)) from s = sin x, c = cos x and |d| <= ROTATE_MAX: the angle-sum
    formulas with Taylor series of sin d and cos d (a few multiplications: a sine and a cosine
    cost ~14 ns, this ~3 ns; each result within an ulp or two of the library's)."""
    d2 = d * d
    cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 * (1.0 / 720.0)))
    sd = d * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0 - d2 * (1.0 / 5040.0))))
    return s * cd + c * sd, c * cd - s * sd


@nb.njit(cache=True, error_model="numpy")
def states_kernel(orb: NDArray, times: NDArray, out: NDArray, nus: NDArray) -> None:
    """Vectorised :func:`state_kernel`: ``out[k] = x(times[k])``, ``nus[k]`` its true anomaly."""
    for k in range(times.shape[0]):
        nus[k] = state_kernel(orb, times[k], out[k])


@nb.njit(cache=True, error_model="numpy")
def osculating_params_kernel(x: NDArray, mu: float, out: NDArray) -> None:
    """The packed orbit (layout ``P_*``) of the osculating ellipse of state x[0:6] (km, km/s),
    with its mean anomaly at the state's own time (t = 0). A circular orbit (e < 1e-12) takes
    the position's direction as its periapsis."""
    rx, ry, rz, vx, vy, vz = x[0], x[1], x[2], x[3], x[4], x[5]
    r = math.sqrt(rx * rx + ry * ry + rz * rz)
    v2 = vx * vx + vy * vy + vz * vz
    a = 1.0 / (2.0 / r - v2 / mu)
    hx, hy, hz = ry * vz - rz * vy, rz * vx - rx * vz, rx * vy - ry * vx
    h = math.sqrt(hx * hx + hy * hy + hz * hz)
    rv = rx * vx + ry * vy + rz * vz
    c1 = v2 / mu - 1.0 / r
    ex, ey, ez = c1 * rx - rv / mu * vx, c1 * ry - rv / mu * vy, c1 * rz - rv / mu * vz
    e = math.sqrt(ex * ex + ey * ey + ez * ez)
    if e < 1e-12:
        px, py, pz = rx / r, ry / r, rz / r
    else:
        px, py, pz = ex / e, ey / e, ez / e
    qx, qy, qz = (hy * pz - hz * py) / h, (hz * px - hx * pz) / h, (hx * py - hy * px) / h
    cos_nu = (px * rx + py * ry + pz * rz) / r
    sin_nu = (qx * rx + qy * ry + qz * rz) / r
    s1e = math.sqrt(1.0 - e * e)
    big_e = math.atan2(s1e * sin_nu, e + cos_nu)
    out[P_A] = a
    out[P_E] = e
    out[P_MU] = mu
    out[P_N] = math.sqrt(mu / (a * a * a))
    out[P_M0] = big_e - e * math.sin(big_e)
    out[5], out[6], out[7] = px, py, pz
    out[8], out[9], out[10] = qx, qy, qz
    out[P_S1E] = s1e
    out[P_SQMUA] = math.sqrt(mu * a)


@nb.njit(cache=True, error_model="numpy")
def osculating_orbit_kernel(x: NDArray, mu: float, t: float, out: NDArray) -> tuple[bool, float, float, float]:
    """The packed orbit of state x[0:6] (km, km/s) at time t (s) into ``out`` (mean anomaly at
    t = 0) and its angles (inclination, RAAN, argument of periapsis; rad) read off the perifocal
    vectors P, Q and W = P x Q: (ok, i, raan, argp); ok False when x is not finite or not on an
    ellipse. An equatorial orbit (sin i <= 1e-12) has RAAN 0 and its periapsis measured from x."""
    r = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
    v2 = x[3] * x[3] + x[4] * x[4] + x[5] * x[5]
    if not (math.isfinite(r + x[3] + x[4] + x[5]) and r > 0.0 and 0.5 * v2 < mu / r):
        return False, 0.0, 0.0, 0.0
    osculating_params_kernel(x, mu, out)
    out[P_M0] -= out[P_N] * t
    px, py, pz, qx, qy, qz = out[5], out[6], out[7], out[8], out[9], out[10]
    wx, wy, wz = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
    inc = math.acos(min(1.0, max(-1.0, wz)))
    two_pi = 2 * math.pi
    if math.sin(inc) > 1e-12:
        return True, inc, math.atan2(wx, -wy) % two_pi, math.atan2(pz, qz) % two_pi
    return True, inc, 0.0, math.atan2(py, px) % two_pi


def _rotation_pq(i: float, raan: float, argp: float) -> tuple[NDArray, NDArray]:
    """Perifocal unit vectors P (to periapsis) and Q in ECI for angles in radians."""
    cO, sO = math.cos(raan), math.sin(raan)
    cw, sw = math.cos(argp), math.sin(argp)
    ci, si = math.cos(i), math.sin(i)
    p = np.array([cO * cw - sO * sw * ci, sO * cw + cO * sw * ci, sw * si])
    q = np.array([-cO * sw - sO * cw * ci, -sO * sw + cO * cw * ci, cw * si])
    return p, q


def true_to_mean_anomaly(nu: float, e: float) -> float:
    """Mean anomaly (rad) of true anomaly ``nu`` (rad) on an ellipse of eccentricity e.

    Scalar, with the C library's functions as the compiled kernels: numpy's float64 arctan2
    dispatches to AVX-512 code on processors that have it and differs there in the last bits
    (1-3 ulp of M0 for 7 % of true anomalies, measured; docs/reproducibility.md)."""
    big_e = 2.0 * math.atan2(math.sqrt(1.0 - e) * math.sin(nu / 2),
                             math.sqrt(1.0 + e) * math.cos(nu / 2))
    return big_e - e * math.sin(big_e)


@dataclass(frozen=True)
class KeplerOrbit:
    """An unforced elliptic orbit, propagated analytically forward and backward in time.

    Attributes are the classical elements (km, rad) and the mean anomaly ``m0`` at t = 0.
    """

    a: float
    e: float
    i: float
    raan: float
    argp: float
    m0: float
    mu: float

    @classmethod
    def from_config(cls, cfg: OrbitConfig) -> "KeplerOrbit":
        nu0 = math.radians(cfg.nu0_deg)
        return cls(cfg.a_km, cfg.e, math.radians(cfg.i_deg), math.radians(cfg.raan_deg),
                   math.radians(cfg.argp_deg), true_to_mean_anomaly(nu0, cfg.e), cfg.mu_km3_s2)

    @classmethod
    def from_state(cls, x: ArrayLike, t: float, mu: float) -> "KeplerOrbit":
        """The osculating orbit of ECI state x (km, km/s) at time t (s since epoch).

        Built from the packed form in one compiled call (:func:`osculating_orbit_kernel`: a
        governor re-anchors on every update under a J2 truth)."""
        x = np.ascontiguousarray(x, dtype=float)
        arr = np.empty(N_PARAMS)
        ok = x.shape == (6,)   # checked before the kernel, which is compiled for 1-d states
        if ok:
            ok, inc, raan, argp = osculating_orbit_kernel(x, float(mu), float(t), arr)
        if not ok:
            raise StateError(f"state is not on an elliptic orbit: {x}")
        arr.setflags(write=False)
        # The dataclass's frozen __init__ sets each field through object.__setattr__ (~1 us of the
        # ~3 us this costs; a governor under a J2 truth re-anchors on every update): the same
        # fields, set at once.
        orbit = object.__new__(cls)
        orbit.__dict__.update(a=float(arr[P_A]), e=float(arr[P_E]), i=inc, raan=raan, argp=argp,
                              m0=float(arr[P_M0]), mu=mu, _params=arr)
        return orbit

    @property
    def mean_motion(self) -> float:
        """n = sqrt(mu / a^3) in rad/s."""
        return math.sqrt(self.mu / self.a**3)

    @property
    def period(self) -> float:
        """Orbital period 2 pi / n in s."""
        return 2.0 * math.pi / self.mean_motion

    @property
    def params(self) -> NDArray:
        """Packed float64 array for the compiled kernels (layout ``P_*`` above)."""
        try:
            return self._params  # type: ignore[has-type]
        except AttributeError:
            p, q = _rotation_pq(self.i, self.raan, self.argp)
            arr = np.empty(N_PARAMS)
            arr[:5] = (self.a, self.e, self.mu, self.mean_motion, self.m0)
            arr[P_PVEC] = p
            arr[P_QVEC] = q
            arr[P_S1E] = math.sqrt(1.0 - self.e**2)
            arr[P_SQMUA] = math.sqrt(self.mu * self.a)
            arr.setflags(write=False)
            object.__setattr__(self, "_params", arr)
            return arr

    def state(self, t: ArrayLike) -> NDArray:
        """ECI state(s) [r; v] at time(s) t (s since epoch): shape t.shape + (6,)."""
        return self.state_and_anomaly(t)[0]

    def state_and_anomaly(self, t: ArrayLike) -> tuple[NDArray, NDArray]:
        """States (..., 6) and true anomalies (...) in [0, 2 pi) at times t (s since epoch)."""
        if isinstance(t, float):  # one time (a Python or numpy double), as a node asks every step:
            if not math.isfinite(t):   # the same kernel, without wrapping t in arrays (~8 -> ~1 us)
                raise StateError(f"orbit propagation time must be finite, got {t!r}")
            out = np.empty(6)
            return out, np.float64(state_kernel(self.params, t, out))
        t_arr = np.asarray(t, dtype=float)
        if not np.all(np.isfinite(t_arr)):
            raise StateError(f"orbit propagation time must be finite, got {t!r}")
        flat = np.ascontiguousarray(t_arr.reshape(-1))
        out = np.empty((flat.size, 6))
        nus = np.empty(flat.size)
        states_kernel(self.params, flat, out, nus)
        return out.reshape(t_arr.shape + (6,)), nus.reshape(t_arr.shape)


def elements_to_state(a: ArrayLike, e: ArrayLike, i: ArrayLike, raan: ArrayLike, argp: ArrayLike,
                      nu: ArrayLike, mu: float) -> NDArray:
    """Cartesian ECI state(s) (..., 6) from classical elements (km, rad), broadcast together."""
    a, e, i, raan, argp, nu = np.broadcast_arrays(*(np.asarray(v, dtype=float)
                                                    for v in (a, e, i, raan, argp, nu)))
    p_semi = a * (1.0 - e**2)
    r = p_semi / (1.0 + e * np.cos(nu))
    r_pf = np.stack([r * np.cos(nu), r * np.sin(nu)], axis=-1)
    k = np.sqrt(mu / p_semi)
    v_pf = np.stack([-k * np.sin(nu), k * (e + np.cos(nu))], axis=-1)
    cO, sO, cw, sw, ci, si = np.cos(raan), np.sin(raan), np.cos(argp), np.sin(argp), np.cos(i), np.sin(i)
    pvec = np.stack([cO * cw - sO * sw * ci, sO * cw + cO * sw * ci, sw * si], axis=-1)
    qvec = np.stack([-cO * sw - sO * cw * ci, -sO * sw + cO * cw * ci, cw * si], axis=-1)
    rr = r_pf[..., :1] * pvec + r_pf[..., 1:] * qvec
    vv = v_pf[..., :1] * pvec + v_pf[..., 1:] * qvec
    return np.concatenate([rr, vv], axis=-1)


def state_to_elements(x: ArrayLike, mu: float) -> dict[str, NDArray]:
    """Classical elements of elliptic ECI state(s) (..., 6): a (km), e, i, raan, argp, nu (rad).

    Angles lie in [0, 2 pi) (i in [0, pi]). Circular or equatorial orbits leave argp/raan
    undefined; they are then set to 0 and the anomaly is measured from the next defined axis.
    Raises :class:`StateError` for non-finite, degenerate (r = 0) or unbound states.
    """
    x = np.asarray(x, dtype=float)
    check_states(x, "state")
    r, v = x[..., :3], x[..., 3:]
    rn = np.linalg.norm(r, axis=-1)
    vn2 = np.einsum("...i,...i->...", v, v)
    energy = 0.5 * vn2 - mu / rn
    if np.any(energy >= 0):
        raise StateError("state is not on an elliptic orbit (specific energy >= 0)")
    a = -mu / (2.0 * energy)
    h = np.cross(r, v)
    hn = np.linalg.norm(h, axis=-1)
    if np.any(hn <= 1e-12 * rn * np.sqrt(vn2)):
        raise StateError("state is degenerate: position and velocity are parallel (rectilinear orbit)")
    evec = np.cross(v, h) / mu - r / rn[..., None]
    e = np.linalg.norm(evec, axis=-1)
    i = np.arccos(np.clip(h[..., 2] / hn, -1.0, 1.0))
    nvec = np.stack([-h[..., 1], h[..., 0], np.zeros_like(hn)], axis=-1)
    nn = np.linalg.norm(nvec, axis=-1)
    eps = 1e-11
    safe_n = np.where(nn > eps * hn, nn, 1.0)
    raan = np.where(nn > eps * hn, np.mod(np.arctan2(nvec[..., 1], nvec[..., 0]), 2 * np.pi), 0.0)
    node = np.where((nn > eps * hn)[..., None], nvec / safe_n[..., None],
                    np.broadcast_to(np.array([1.0, 0.0, 0.0]), nvec.shape))
    safe_e = np.where(e > eps, e, 1.0)
    e_hat = np.where((e > eps)[..., None], evec / safe_e[..., None], node)
    hhat = h / hn[..., None]

    def angle(frm: NDArray, to: NDArray) -> NDArray:
        c = np.einsum("...i,...i->...", frm, to)
        s = np.einsum("...i,...i->...", np.cross(frm, to), hhat)
        return np.mod(np.arctan2(s, c), 2 * np.pi)

    argp = np.where(e > eps, angle(node, e_hat), 0.0)
    nu = angle(e_hat, r / rn[..., None])
    return {"a": a, "e": e, "i": i, "raan": raan, "argp": argp, "nu": nu}


def check_states(x: NDArray, name: str) -> None:
    """Raise :class:`StateError` unless every state (..., 6) is finite with a non-zero position."""
    if x.shape[-1:] != (6,):
        raise StateError(f"{name} must have 6 components [r (km); v (km/s)], got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise StateError(f"{name} has non-finite components: {x}")
    if np.any(np.linalg.norm(x[..., :3], axis=-1) < 1.0):
        raise StateError(f"{name} is degenerate: position within 1 km of Earth's centre")


def vnb_frame(x_c: ArrayLike) -> NDArray:
    """Rotation(s) ECI -> VNB of the chief state(s) x_c (..., 6): rows x̂, ŷ, ẑ (..., 3, 3).

    x̂ = v_c/|v_c|, ŷ = (r_c × x̂)/|r_c × x̂|, ẑ = x̂ × ŷ  (SPEC §1). ``R @ p_eci`` gives VNB.
    """
    x_c = np.asarray(x_c, dtype=float)
    xh = x_c[..., 3:] / np.linalg.norm(x_c[..., 3:], axis=-1, keepdims=True)
    yh = np.cross(x_c[..., :3], xh)
    yh /= np.linalg.norm(yh, axis=-1, keepdims=True)
    zh = np.cross(xh, yh)
    return np.stack([xh, yh, zh], axis=-2)


def lvlh_frame(x_c: ArrayLike) -> NDArray:
    """Rotation(s) ECI -> LVLH of the chief state(s) x_c (..., 6): rows x̂, ŷ, ẑ (..., 3, 3).

    x̂ = r_c/|r_c| (radial, away from Earth), ẑ = (r_c × v_c)/|r_c × v_c| (orbit normal),
    ŷ = ẑ × x̂ (along-track: the chief's velocity on a circular orbit; on an elliptic one v_c
    leans out of ŷ by the flight-path angle, toward +x̂ while the radius grows). ``R @ p_eci``
    gives LVLH.
    """
    x_c = np.asarray(x_c, dtype=float)
    xh = x_c[..., :3] / np.linalg.norm(x_c[..., :3], axis=-1, keepdims=True)
    zh = np.cross(x_c[..., :3], x_c[..., 3:])
    zh /= np.linalg.norm(zh, axis=-1, keepdims=True)
    yh = np.cross(zh, xh)
    return np.stack([xh, yh, zh], axis=-2)
