"""Identification of a tumbling target's dynamics from a tracked motion history.

A rigid body free of torque keeps its angular momentum, so its next tens of seconds are
fixed by its principal axes, its two inertia ratios, its angular velocity at one instant and
the path of its centre of mass. [`identify`][jaxpose.identify] estimates all of them from the
motions that [`jaxpose.track`][] measures, and [`Dynamics.predict`][jaxpose.Dynamics.predict]
carries them past the data.

**Frames and conventions.** Frame c is the camera frame, by default taken as inertial: a
chaser that holds its attitude, and no orbital dynamics over the window. The measured motion
from the first frame to frame k is x ↦ R_k x + t_k in frame c (metres). The body's principal
frame b has its axes along the columns of P (frame c at the first frame's time), ordered so
that J1 ≤ J2 ≤ J3. Its attitude A(t) maps frame b to frame c at t = 0, with A(0) = P. Then
R(t) = A(t) Pᵀ, and Euler's equations J ω̇ = −ω × Jω hold for the body rate ω in frame b.
With an [`Orbit`][jaxpose.Orbit] (a camera fixed in the orbital frame), R(t) = Q(t) A(t) Pᵀ
with the camera's own turn Q(t), and the gravity-gradient torque 3n² e × J e enters
Euler's equations.

**Fit, in three steps:**

1. *Initial inertia, linear.* The rate u_k = log(R_{k−h}ᵀ R_{k+h}) / (t_{k+h} − t_{k−h})
   is the body rate in the first frame's axes (centred differences over ±h frames). The
   angular momentum R_k M u_k and the energy u_kᵀ M u_k are constant for the inertia tensor
   M = P J Pᵀ expressed in those axes. Both are linear in M's six entries, so M comes from
   the smallest singular vector of the stacked deviations from their means. Its eigenvectors
   give P and its eigenvalues the ratios. Where the body rate's direction moves little,
   M + c·I is nearly as constant and the two smallest singular vectors share M, so each start
   tries `START_MIXES` tensors in their span, the least-squares one first, and keeps the one
   of least cost of step 2 (`inertia_candidates`). Three starts, from h, 2h and 4h
   (`START_WINDOWS`).
2. *Attitude, nonlinear.* optimistix Levenberg–Marquardt over the axes (a rotation vector
   on the left of P), the two ratios (as logarithms) and the first frame's rate in frame c,
   from each start; the fit of least cost is kept. The residuals compare each measured
   motion keyframe j → k (a tracker registers frame k against keyframe j) with the model's
   R(t_k) R(t_j)ᵀ, as a left rotation vector whitened by the measurement's covariance.
   Comparing the chained R_0k instead would count every keyframe's error again in all later
   frames. R(t) is integrated by diffrax through Euler's equations and the quaternion
   kinematics (forward-mode differentiable).
   *The keyframes' shared error.* Every frame registered against one keyframe inherits that
   keyframe's own range noise, so their errors move together. Two more fits
   (`SHARED_ROUNDS`) estimate the ratio ρ of that shared variance to each frame's own from
   the last fit's residuals (`shared_variance_ratio`) and whiten each keyframe's residuals
   by the inverse square root of I + ρ 11ᵀ (`decorrelated`: generalised least squares).
3. *Centre of mass, linear.* A point that the body turns about moves on a straight line,
   c + v t, so each motion j → k maps c + t_j v to c + t_k v:
   t_jk = (I − R_jk) c + (t_k I − t_j R_jk) v, linear in (c, v), solved by least squares,
   then again on rows decorrelated for the keyframes' shared error in the same way.

**Uncertainty and observability.** Each block's covariance is σ̂² (JᵀJ)⁻¹ at the solution,
with σ̂² the whitened, decorrelated residuals' variance (1 when the measurement covariances
are right), times a design effect: whatever of a keyframe's shared noise the decorrelation
left makes its frames' residuals move together, so they count as fewer independent ones. The
eigenvalues of JᵀJ are floored, so that a direction the data leave free gets a huge
variance, not none. *Split check:* an error that wanders slowly over the window (a track
against a drifting body-frame model) looks like other dynamics, so the fit absorbs it and no
residual shows it. Two more rounds of the same least-squares program fit each half of the
window alone, from the whole window's solution; where their ratios disagree by more than
their own standard deviations allow (χ² of the difference, `_split_inflation`), the
attitude covariance is multiplied by that χ². The centre's linear fit is solved on each half
alone too, and its covariance multiplied by the χ² of the halves' (c, v). Consistent halves
leave them as they are; a bias that both halves share passes the check.
A spin about a principal axis leaves the ratios unobservable: the body rate's direction does
not move. `observable` is False when the fitted body rate's direction
stays within `MIN_EXCITATION` of its mean, when a ratio's standard deviation exceeds `MAX_RATIO_REL_STD`
(1 %) of it, or when the ratios break a rigid body's J1 + J2 ≥ J3. The ratios are then not to be trusted.
Two nearly equal moments leave their two axes free to turn about the third: their
covariance says so.
"""

from __future__ import annotations

import math

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._tree import tree_select
from ._track import Track, chained_motions

RATE_WINDOW_S = 0.5
"""Half-width (s) of the centred differences that give the initial body rates: long enough
to average a registration's noise (≈ 0.05° per frame), short against a tumble's period."""

MIN_EXCITATION = math.radians(2.0)
"""Least spread (rad) of the body rate's direction over the window for the inertia ratios to
count as observable: a spin about a principal axis keeps that direction fixed."""

MAX_RATIO_REL_STD = 0.01
"""Largest standard deviation of an inertia ratio, relative to the ratio, for `observable` to
be True. Strict, because on tracked tumbles the covariance is optimistic: the registrations'
errors are not white (on the N5 tumble of `experiments/identify.py` a ratio was 8 of its
standard deviations off)."""

MIN_FRAMES = 10
"""Fewest frames with a successful registration that `identify` accepts."""

MAX_ODE_STEPS = 16384
"""Step limit of one integration of Euler's equations (a minute of tumbling takes hundreds)."""

MIN_MOMENT = 0.05
"""Smallest moment relative to the largest that the linear start takes (J1 + J2 ≥ J3 for a
rigid body, so only a thin rod comes near 0)."""

TRIANGLE_TOL = 0.02
"""How far J1/J3 + J2/J3 may fall below 1 (a rigid body has J1 + J2 ≥ J3) for `observable`."""

INFORMATION_FLOOR = 1e-12
"""Least eigenvalue of the information JᵀJ, relative to its largest, in the covariances: a
direction the data do not constrain gets a huge variance, never zero."""

SHARED_ROUNDS = 2
"""Refits after the first least-squares fit, each with the keyframes' shared error estimated
from the last fit's residuals (`shared_variance_ratio`, `decorrelated`); 0 fits once with
the registrations taken as independent."""

CENTRE_FREE_STD = 2.5
"""Standard deviation (m) of the centre of mass along a rotation axis that never moved
(`fit_centre`'s free axis): half the largest target the estimator takes (about 5 m across);
there the centre is pinned to the first view's tracked point, which lies on the target."""

START_MIXES = 12
"""Inertia tensors each linear start tries (`inertia_candidates`), spread over half a turn in
the span of step 1's two smallest singular vectors; the one of least cost starts the fit."""

START_WINDOWS = (1, 2, 4)
"""Multiples of the rate window whose linear starts (`linear_start`) are each fitted; the
fit with the least cost is kept. Least squares through Euler's equations has local minima,
and which start lands in the right one depends on the registrations' noise: on simulated
tumbles with 0.1–0.3° of noise per registration, a single start ended in fits 2–22 times
costlier than the truth (`docs/tracking.md`)."""

RESIDUAL_UNIT = 1e-3
"""Rotation residuals are scaled to milliradians inside the least squares (conditioning)."""


def _float_array(x) -> Array:
    """`x` as an array of JAX's default float type, never weakly typed, so that every Orbit
    of one precision shares a compiled program."""
    return jnp.asarray(x, dtype=jnp.result_type(float))


class Orbit(eqx.Module):
    """How the camera frame turns relative to an inertial frame, and the gravity gradient.

    A chaser that holds its camera fixed in the orbital frame o of a circular orbit (z_o
    radially outward, x_o along the track, y_o the orbit normal; o turns about +y_o at the
    mean motion n relative to the inertial frame that coincides with o at t = 0) sees the
    target turn by the orbit as well, and the target feels the gravity-gradient torque
    3n² e × J e, with e the local vertical in body axes. `rate` = 0: a camera that holds an
    inertial attitude, and no torque.

    **Fields:** `rate` n (rad/s); `camera_from_orbit` C (3, 3), whose rows are the camera's
    axes in frame o (`jaxpose.sim.C_FROM_O` for the simulator's chaser).
    """

    rate: Float[Array, ""] = eqx.field(converter=_float_array)
    camera_from_orbit: Float[Array, "3 3"] = eqx.field(converter=_float_array)

    @classmethod
    def inertial(cls, dtype=None) -> Orbit:
        """A camera that holds an inertial attitude: no orbit, no torque."""
        return cls(jnp.zeros((), dtype), jnp.eye(3, dtype=dtype))

    def camera_turn(self, times: Float[Array, " T"]) -> Float[Array, "T 3 3"]:
        """Q(t) = C R_y(nt)ᵀ Cᵀ: maps vectors in frame c at t = 0 to frame c at each time."""
        c, s = jnp.cos(self.rate * times), jnp.sin(self.rate * times)
        zero, one = jnp.zeros_like(times), jnp.ones_like(times)
        o_from_i = jnp.stack(
            [jnp.stack([c, zero, -s], -1), jnp.stack([zero, one, zero], -1), jnp.stack([s, zero, c], -1)], -2
        )
        return jnp.einsum("ij,tjk,lk->til", self.camera_from_orbit, o_from_i, self.camera_from_orbit)

    def vertical(self, t: Float[Array, ""]) -> Float[Array, "3"]:
        """The local vertical (radially outward) at time t, in frame c at t = 0."""
        up = jnp.stack([jnp.sin(self.rate * t), jnp.zeros_like(t), jnp.cos(self.rate * t)])
        return self.camera_from_orbit @ up


class Dynamics(eqx.Module):
    """A tumbling target's identified dynamics.

    **Fields** (frame c at the first frame's time t = 0):

    - `inertia_ratios`: (J1/J3, J2/J3), with J1 ≤ J2 ≤ J3.
    - `principal_axes`: (3, 3); column i is the axis of J_i (a rotation matrix).
    - `centre`: the centre of mass (m).
    - `velocity`: the centre of mass's velocity (m/s).
    - `omega`: the angular velocity at t = 0 (rad/s), inertial: with an orbiting camera
      (`orbit`), the target's turn less the camera's own is what the camera sees.
    - `covariance`: (14, 14) over (δaxes (3, rad, a rotation vector on the left of
      `principal_axes`), ratios (2), omega (3, rad/s), centre (3, m), velocity (3, m/s)). The
      attitude block and the centre block are fitted separately, so their cross terms are
      zero.
    - `observable`: whether the window excites the inertia (see the module's notes).
    - `excitation`: spread of the body rate's direction over the window (rad).
    - `rotation_rms`: RMS of the fitted rotation residuals (rad).
    - `centre_rms`: RMS of the fitted translation residuals (m).
    - `result`: the Levenberg–Marquardt fit's `optx.RESULTS`.
    - `frames`: frames used (successful registrations).
    - `orbit`: the camera's [`Orbit`][jaxpose.Orbit] the fit assumed (None: a camera that
      holds an inertial attitude, torque-free).
    """

    inertia_ratios: Float[Array, "2"]
    principal_axes: Float[Array, "3 3"]
    centre: Float[Array, "3"]
    velocity: Float[Array, "3"]
    omega: Float[Array, "3"]
    covariance: Float[Array, "14 14"]
    observable: Bool[Array, ""]
    excitation: Float[Array, ""]
    rotation_rms: Float[Array, ""]
    centre_rms: Float[Array, ""]
    result: optx.RESULTS
    frames: Int[Array, ""]
    orbit: Orbit | None = None

    @property
    def moments(self) -> Float[Array, "3"]:
        """(J1, J2, J3) / J3."""
        return jnp.concatenate([self.inertia_ratios, jnp.ones(1, self.inertia_ratios.dtype)])

    def predict(self, times: Float[ArrayLike, " T"]) -> tuple[Float[Array, "T 3 3"], Float[Array, "T 3"]]:
        """The target's motion from the first frame to each time: x ↦ R x + t in frame c.

        `times`: seconds since the first frame, ascending and ≥ 0, past the data included.
        **Returns:** rotations (T, 3, 3) and translations (T, 3) (m).
        """
        times = jnp.asarray(times, self.omega.dtype)
        R = motion_rotations(self.principal_axes, self.moments, self.omega, times, self.orbit)
        t = self.centre[None] + times[:, None] * self.velocity[None] - R @ self.centre
        return R, t

    def rates(self, times: Float[ArrayLike, " T"]) -> Float[Array, "T 3"]:
        """The target's angular velocity as the camera sees it at each time: ω(t) with
        Ṙ Rᵀ = [ω(t)]× for the motion R(t) of [`predict`][jaxpose.Dynamics.predict] (rad/s, in
        frame c at that time), the quantity `rate` of [`jaxpose.Track`][] estimates frame by frame.

        `times`: seconds since the first frame, ascending and ≥ 0, past the data included.

        With R = Q A Pᵀ (`motion_rotations`), Ṙ Rᵀ = Q̇ Qᵀ + Q Ȧ Aᵀ Qᵀ: the camera's own turn
        −n C e_y (an orbiting camera, `Orbit`; zero for an inertial one) plus the body's rate
        ω_b(t) from Euler's equations turned into frame c at time t by Q A = R P.
        """
        times = jnp.asarray(times, self.omega.dtype)
        R, body = _integrate(self.principal_axes, self.moments, self.omega, times, self.orbit)
        orbit = Orbit.inertial(self.omega.dtype) if self.orbit is None else self.orbit
        camera_turn = -orbit.rate * orbit.camera_from_orbit[:, 1]
        return jnp.einsum("tij,jk,tk->ti", R, self.principal_axes, body) + camera_turn[None]

    def predict_point(
        self, point: Float[ArrayLike, "3"], times: Float[ArrayLike, " T"]
    ) -> tuple[Float[Array, "T 3"], Float[Array, "T 3"]]:
        """Where a point of the target (frame c at t = 0, m) is at each time, and its standard
        deviation per axis (m) from `covariance`, propagated to first order.

        `times`: seconds since the first frame, ascending and ≥ 0.
        """
        point = jnp.asarray(point, self.omega.dtype)
        times = jnp.asarray(times, self.omega.dtype)

        def path(theta):
            axes = jaxlie.SO3.exp(theta[:3]).as_matrix() @ self.principal_axes
            moments = jnp.concatenate([theta[3:5], jnp.ones(1, theta.dtype)])
            R = motion_rotations(axes, moments, theta[5:8], times, self.orbit)
            centre, velocity = theta[8:11], theta[11:14]
            return R @ (point - centre) + centre[None] + times[:, None] * velocity[None]

        theta = jnp.concatenate(
            [jnp.zeros(3, point.dtype), self.inertia_ratios, self.omega, self.centre, self.velocity]
        )
        positions = path(theta)
        jac = jax.jacfwd(path)(theta)  # (T, 3, 14)
        var = jnp.einsum("tip,pq,tiq->ti", jac, self.covariance, jac)
        return positions, jnp.sqrt(jnp.maximum(var, 0.0))


def euler_rhs(t, state: Float[Array, "7"], args) -> Float[Array, "7"]:
    """Euler's equations in principal axes with the gravity-gradient torque, and the
    quaternion kinematics q̇ = ½ q ⊗ (0, ω). state = (q (4, wxyz, body b → frame c at t = 0),
    ω (3, rad/s, frame b, inertial)); args = (moments (J1, J2, J3) up to scale, `Orbit`)."""
    moments, orbit = args
    q, w = state[:4], state[4:]
    vertical = jaxlie.SO3(wxyz=q).inverse().apply(orbit.vertical(t))
    torque = 3 * orbit.rate**2 * jnp.cross(vertical, moments * vertical)
    w_dot = (torque - jnp.cross(w, moments * w)) / moments
    pure = jnp.concatenate([jnp.zeros(1, w.dtype), w])
    q_dot = 0.5 * (jaxlie.SO3(wxyz=q) @ jaxlie.SO3(wxyz=pure)).wxyz
    return jnp.concatenate([q_dot, w_dot])


def motion_rotations(
    axes: Float[Array, "3 3"],
    moments: Float[Array, "3"],
    omega: Float[Array, "3"],
    times: Float[Array, " T"],
    orbit: Orbit | None = None,
) -> Float[Array, "T 3 3"]:
    """R(t) = Q(t) A(t) Pᵀ at `times` (s ≥ 0, ascending) for principal axes P = `axes`
    (frame c at t = 0), moments (J1, J2, J3) up to scale and the inertial angular velocity
    `omega` at t = 0 (rad/s, frame c at t = 0); A(t) is the body's attitude in frame c at
    t = 0 and Q(t) the camera's turn (`Orbit.camera_turn`; the identity for None, an inertial
    camera). diffrax (Tsit5, adaptive), forward-mode differentiable."""
    return _integrate(axes, moments, omega, times, orbit)[0]


def _integrate(axes, moments, omega, times, orbit=None) -> tuple[Float[Array, "T 3 3"], Float[Array, "T 3"]]:
    """`motion_rotations` and the body rates ω(t) (rad/s, principal axes) at `times`."""
    dtype = omega.dtype
    orbit = Orbit.inertial() if orbit is None else orbit
    tol = 100 * float(jnp.finfo(dtype).eps)
    q0 = jaxlie.SO3.from_matrix(axes).wxyz
    y0 = jnp.concatenate([q0, axes.T @ omega])
    t1 = jnp.maximum(times[-1], jnp.asarray(1e-6, dtype))
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(euler_rhs),
        diffrax.Tsit5(),
        t0=jnp.asarray(0.0, dtype),
        t1=t1,
        dt0=None,
        y0=y0,
        args=(moments, orbit),
        saveat=diffrax.SaveAt(ts=times),
        stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol),
        adjoint=diffrax.ForwardMode(),
        max_steps=MAX_ODE_STEPS,
        throw=False,
    )
    # A failed solve (moments so uneven that the equations turn stiff, tried by a least-squares
    # step) gives no motion, which the residuals then reject: never a NaN.
    solved = (sol.result == diffrax.RESULTS.successful) & jnp.all(jnp.isfinite(sol.ys))
    q = jnp.where(solved, sol.ys[:, :4], jnp.array([1.0, 0.0, 0.0, 0.0], dtype)[None])
    q = q / jnp.linalg.norm(q, axis=1, keepdims=True)
    A = jax.vmap(lambda qk: jaxlie.SO3(wxyz=qk).as_matrix())(q)
    rates = jnp.where(solved, sol.ys[:, 4:], (axes.T @ omega)[None])
    R = jnp.einsum("tij,tjk,lk->til", orbit.camera_turn(times), A, axes)
    return jnp.where(solved, R, jnp.eye(3, dtype=dtype)[None]), rates


def body_rates(
    times: Float[Array, " T"], rotations: Float[Array, "T 3 3"], valid: Bool[Array, " T"], half: int
) -> tuple[Float[Array, "T 3"], Bool[Array, " T"]]:
    """u_k = log(R_{k−h}ᵀ R_{k+h}) / (t_{k+h} − t_{k−h}): the body rate in the first frame's axes
    (rad/s), by centred differences over ±`half` frames; and where both ends are valid."""
    T = times.shape[0]
    index = jnp.arange(T)
    lo, hi = jnp.clip(index - half, 0, T - 1), jnp.clip(index + half, 0, T - 1)
    inside = (index - half >= 0) & (index + half <= T - 1)
    ok = inside & valid[lo] & valid[hi]
    rel = jnp.einsum("tji,tjk->tik", rotations[lo], rotations[hi])
    rel = jnp.where(ok[:, None, None], rel, jnp.eye(3, dtype=rel.dtype)[None])
    logs = jax.vmap(lambda M: jaxlie.SO3.from_matrix(M).log())(rel)
    span = jnp.where(ok, times[hi] - times[lo], 1.0)
    return logs / span[:, None], ok


def _momentum_rows(R: Float[Array, "3 3"], u: Float[Array, "3"]) -> Float[Array, "4 6"]:
    """Rows that map M's entries m = (M11, M22, M33, M12, M13, M23) to the angular momentum
    R M u (3 rows) and the energy uᵀ M u / |u| (1 row, momentum units)."""
    u1, u2, u3 = u
    z = jnp.zeros_like(u1)
    B = jnp.stack(
        [
            jnp.stack([u1, z, z, u2, u3, z]),
            jnp.stack([z, u2, z, u1, z, u3]),
            jnp.stack([z, z, u3, z, u1, u2]),
        ]
    )
    energy = (u @ B) / jnp.maximum(jnp.linalg.norm(u), 1e-12)
    return jnp.concatenate([R @ B, energy[None]])


def _tensor(m: Float[Array, "6"]) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """Principal axes (det +1) and moments (ascending, divided by the largest, each at least
    `MIN_MOMENT` of it) of the symmetric tensor with entries m = (M11, M22, M33, M12, M13,
    M23), its sign chosen for a positive trace."""
    M = jnp.array([[m[0], m[3], m[4]], [m[3], m[1], m[5]], [m[4], m[5], m[2]]])
    M = M * jnp.sign(jnp.trace(M) + 1e-30)
    evals, evecs = jnp.linalg.eigh(M)
    evals = jnp.maximum(evals, MIN_MOMENT * evals[2])
    return _right_handed(evecs), evals / evals[2]


def inertia_candidates(
    rotations: Float[Array, "T 3 3"], rates: Float[Array, "T 3"], ok: Bool[Array, " T"], count: int = START_MIXES
) -> tuple[Float[Array, "K 3 3"], Float[Array, "K 3"]]:
    """Principal axes P (frame c at t = 0, det +1) and moments (J1 ≤ J2 ≤ J3, divided by J3)
    of `count` inertia tensors from conservation of angular momentum and energy (step 1 of
    the module's notes): cos α v₆ + sin α v₅ for α = kπ / `count`, with v₆ and v₅ the two
    smallest right singular vectors of the stacked rows' deviations from their means; the
    first (α = 0) is the least-squares one.

    Why a span and not the smallest vector alone: adding c·I to the inertia tensor changes
    the angular momentum by c times the inertial rate, which moves only as far as the body
    rate's direction does. On a tumble of little excitation that is within the rate noise,
    so the two smallest singular values come out nearly equal and the smallest vector is an
    arbitrary mix of J and I. On the satellite's tumble of `experiments/identify.py
    synthetic` (0.2° of white noise per frame, every frame measured from a noisy first one)
    least squares from the smallest vector alone ended at a cost of 1.0 × 10⁹ against 53,860
    for the noise alone (docs, Tracking: the linear start's span)."""
    rows = jax.vmap(_momentum_rows)(rotations, rates)  # (T, 4, 6)
    w = ok.astype(rows.dtype)[:, None, None]
    mean = jnp.sum(rows * w, axis=0) / jnp.maximum(jnp.sum(w), 1.0)
    dev = ((rows - mean[None]) * w).reshape(-1, 6)
    _, _, vt = jnp.linalg.svd(dev, full_matrices=False)
    angles = jnp.arange(count, dtype=rows.dtype) * (jnp.pi / count)
    mixes = jnp.cos(angles)[:, None] * vt[-1][None] + jnp.sin(angles)[:, None] * vt[-2][None]
    return jax.vmap(_tensor)(mixes)


def _right_handed(axes: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """`axes` with its first column flipped if needed so that det = +1 (still principal axes)."""
    sign = jnp.sign(jnp.linalg.det(axes))
    return axes.at[:, 0].multiply(jnp.where(sign == 0, 1.0, sign))


def _sorted(axes, moments):
    """Axes and moments ordered J1 ≤ J2 ≤ J3, moments divided by J3, axes right-handed."""
    order = jnp.argsort(moments)
    return _right_handed(axes[:, order]), moments[order] / moments[order][2]


def _moments(base: Float[Array, "3"], log_factors: Float[Array, "2"]) -> Float[Array, "3"]:
    """The moments (base1 e^s1, base2 e^s2, base3) / base3: positive for any s."""
    return jnp.concatenate([base[:2] * jnp.exp(log_factors), base[2:]]) / base[2]


def _rotation_residuals(theta, data):
    """Whitened residuals (T, 3) of the measured motions keyframe → k against the model
    θ = (δaxes (3), log moment factors (2), ω (3)) about the base axes and moments. Each
    residual is the left rotation vector of R_meas R_modelᵀ, divided by its standard deviation
    (`whiten`: the inverse Cholesky factors of the rotation covariances, or 1 / `RESIDUAL_UNIT`)."""
    times, rotations, used, references, whiten, base_axes, base_moments, orbit = data
    axes = jaxlie.SO3.exp(theta[:3]).as_matrix() @ base_axes
    moments = _moments(base_moments, theta[3:5])
    R = motion_rotations(axes, moments, theta[5:8], times, orbit)
    model = jnp.einsum("tij,tkj->tik", R, R[references])
    measured = jnp.einsum("tij,tkj->tik", rotations, rotations[references])
    rel = jnp.einsum("tij,tkj->tik", measured, model)
    rel = jnp.where(used[:, None, None], rel, jnp.eye(3, dtype=rel.dtype)[None])
    errors = jax.vmap(lambda M: jaxlie.SO3.from_matrix(M).log())(rel)
    return jnp.einsum("tij,tj->ti", whiten, errors)


def _design_effect(residuals: Float[Array, "T 3"], used: Bool[Array, " T"], references: Int[Array, " T"]):
    """How much the residuals of one keyframe's frames move together: Σ_s |Σ_{k∈s} r_k|² /
    Σ_k |r_k|² over the keyframes s (≥ 1). About 1 for independent residuals and the frames per
    keyframe when each keyframe's noise is shared by all its frames, so that σ̂² (JᵀJ)⁻¹ times
    it does not count correlated residuals as independent ones."""
    r = residuals * used[:, None]
    sums = jax.ops.segment_sum(r, references, num_segments=r.shape[0])
    total = jnp.sum(r**2)
    return jnp.maximum(jnp.sum(sums**2) / jnp.maximum(total, jnp.finfo(r.dtype).tiny), 1.0)


def _decorrelated_residuals(theta, args):
    """`_rotation_residuals` whitened for the keyframes' shared error: args = (data, ρ)."""
    data, ratio = args
    _, _, used, references, *_ = data
    return decorrelated(_rotation_residuals(theta, data), used, references, ratio)


def _attitude_covariance(data, axes, moments, omega, ratio, halves, half_scales):
    """Covariance over (δaxes (3), ratios (2), ω (3)) at the sorted solution: σ̂² (JᵀJ)⁻¹ over
    the whitened residuals decorrelated with the shared-error ratio `ratio` (σ̂² their
    variance: 1 when the measurement covariances are right), times the residuals'
    `_design_effect`; the RMS of the unwhitened rotation residuals (rad); and the two
    ratios' variances from each of the frame masks `halves` (2, T) alone, σ̂_h² (J_hᵀJ_h)⁻¹
    with the whole window's Jacobian rows and each half's own residual variance
    `half_scales` (2,) (`_residual_variance` of its fit; for `_split_inflation`)."""
    times, rotations, used, references, whiten, _, _, orbit = data

    def residuals(phi, weights):
        full = jnp.concatenate([phi[3:5], jnp.ones(1, phi.dtype)])
        base = jaxlie.SO3.exp(phi[:3]).as_matrix() @ axes
        theta = jnp.concatenate([jnp.zeros(5, phi.dtype), phi[5:8]])
        residuals = _rotation_residuals(theta, (times, rotations, used, references, weights, base, full, orbit))
        return decorrelated(residuals, used, references, ratio).reshape(-1)

    phi = jnp.concatenate([jnp.zeros(3, omega.dtype), moments[:2], omega])
    r = residuals(phi, whiten)
    jac = jax.jacfwd(residuals)(phi, whiten)
    n = 3 * jnp.sum(used)
    variance = _residual_variance(r.reshape(-1, 3), used, references)
    half_variances = jax.vmap(lambda mask, scale: scale * _ratio_variances(jac, mask))(halves, half_scales)
    raw = _rotation_residuals(
        jnp.concatenate([jnp.zeros(5, omega.dtype), omega]),
        (
            times,
            rotations,
            used,
            references,
            jnp.broadcast_to(jnp.eye(3, dtype=omega.dtype), whiten.shape),
            axes,
            moments,
            orbit,
        ),
    )
    return variance * _inverse_information(jac.T @ jac), jnp.sqrt(jnp.sum(raw**2) / jnp.maximum(n, 1)), half_variances


def _sorted_ratios(base_moments: Float[Array, "3"], log_factors: Float[Array, "2"]) -> Float[Array, "2"]:
    """(J1/J3, J2/J3) of `_moments`, ordered J1 ≤ J2 ≤ J3."""
    moments = jnp.sort(_moments(base_moments, log_factors))
    return moments[:2] / moments[2]


def _residual_variance(
    residuals: Float[Array, "T 3"], used: Bool[Array, " T"], references, fitted: int = 8
) -> Float[Array, ""]:
    """σ̂² of a fit's whitened, decorrelated residuals over its `used` frames, times their
    `_design_effect`, for `fitted` parameters (8 for the attitude fit, 6 for the centre's)."""
    n = 3 * jnp.sum(used)
    r = residuals * used[:, None]
    return jnp.sum(r**2) / jnp.maximum(n - fitted, 1) * _design_effect(r, used, references)


def _window_halves(times: Float[Array, " T"], used: Bool[Array, " T"]) -> Bool[Array, "2 T"]:
    """The used frames of the window's first and second halves in time (the split check)."""
    later = times >= (times[0] + times[-1]) / 2
    return jnp.stack([used & ~later, used & later])


def _ratio_variances(jac: Float[Array, "R 8"], mask: Bool[Array, " T"]) -> Float[Array, "2"]:
    """diag((J_mᵀJ_m)⁻¹) of the ratios over the rows of the frames in `mask` (3 per frame)."""
    rows = jnp.repeat(mask, 3).astype(jac.dtype)
    return jnp.diag(_inverse_information((jac * rows[:, None]).T @ jac))[3:5]


def _split_inflation(estimates: Float[Array, "2 n"], variances: Float[Array, "2 n"]) -> Float[Array, ""]:
    """The factor (≥ 1) on the whole window's covariance of a block (the attitude's, from the
    ratios; the centre's, from (c, v)): how much more the two half windows' estimates
    disagree than their own variances allow, max over the estimates of
    (x_a − x_b)² / (σ_a² + σ_b²).

    Why: an error that wanders slowly (a track against a drifting body-frame model) looks like
    other dynamics, so the fit absorbs it and no residual shows it; each half, pulled by its
    own part of the error, lands elsewhere. Exact or independent measurements leave the factor
    about 1. A half whose fit or covariance is not finite leaves it at 1."""
    tiny = jnp.finfo(estimates.dtype).tiny
    chi2 = (estimates[0] - estimates[1]) ** 2 / jnp.maximum(variances[0] + variances[1], tiny)
    factor = jnp.max(jnp.where(jnp.isfinite(chi2), chi2, 1.0))
    return jnp.maximum(factor, 1.0)


def _inverse_information(info: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """The inverse of the information JᵀJ with its eigenvalues floored at
    max(`INFORMATION_FLOOR`, n·eps) × the largest: a direction the data leave free (or that the
    float type cannot resolve) gets a huge variance, where a pseudo-inverse would give it
    none; the result is symmetric positive definite."""
    evals, evecs = jnp.linalg.eigh((info + info.T) / 2)
    top = jnp.maximum(evals[-1], jnp.finfo(info.dtype).tiny)
    floor = jnp.maximum(INFORMATION_FLOOR, info.shape[0] * jnp.finfo(info.dtype).eps) * top
    return (evecs / jnp.maximum(evals, floor)[None]) @ evecs.T


def fit_centre(
    times: Float[Array, " T"],
    rotations: Float[Array, "T 3 3"],
    translations: Float[Array, "T 3"],
    used: Bool[Array, " T"],
    references: Int[Array, " T"],
    shared_rounds: int = SHARED_ROUNDS,
    motion_cov: Float[Array, "T 6 6"] | None = None,
    free_axis: tuple[Float[Array, "3"], Bool[Array, ""], Float[Array, "3"] | None] | None = None,
) -> tuple[Float[Array, "6"], Float[Array, "6 6"], Float[Array, ""]]:
    """(c, v) by least squares over the measured motions keyframe j → k (step 3): the centre
    moves from c + t_j v to c + t_k v, so t_jk = (I − R_jk) c + (t_k I − t_j R_jk) v. Also its
    covariance σ̂² (AᵀA)⁻¹ times the residuals' `_design_effect` and the split check's factor
    (each half of the window solved alone, `_split_inflation`), and the residuals' RMS (m).

    With the registrations' covariances `motion_cov` (T, 6, 6; a left rotation vector in rad,
    then the translation in m), each frame's rows are whitened by the covariance of its
    residual (`centre_whitening`, at the unweighted solution): a slide along a face that the
    registration barely holds then weighs little, and a turn about the target itself, which
    moves t_jk but not the residual, not at all. After that, `shared_rounds` solves on rows
    decorrelated for the keyframes' shared error (`shared_variance_ratio` of the last
    whitened residuals, `decorrelated`), as in the rotation fit; the halves use the last
    ratio.

    `free_axis` = (a, free, guess): where `free`, the rotation axis a (unit, frame c at t = 0)
    never moved over the window, so no motion fixes the centre along it (every point of the
    axis turns onto the axis); only the measurements' noise would, and whitened rows trust
    that noise. There c·a is held at guess·a (the first solve's where `guess` is None), the
    rest is fitted, and c·a's variance is `CENTRE_FREE_STD`², so the covariance says what the
    data leave open."""
    eye = jnp.eye(3, dtype=rotations.dtype)
    R_rel = jnp.einsum("tij,tkj->tik", rotations, rotations[references])
    t_rel = translations - jnp.einsum("tij,tj->ti", R_rel, translations[references])
    t_ref = times[references]
    A = jnp.concatenate([eye[None] - R_rel, times[:, None, None] * eye[None] - t_ref[:, None, None] * R_rel], axis=2)

    # Where an axis is free, x = shift + keep y: keep drops c's component along it, and shift
    # holds that component at its guess.
    shift, keep = jnp.zeros(6, A.dtype), jnp.eye(6, dtype=A.dtype)

    def solve(ratio, mask, W):
        """Least squares on the rows of the frames in `mask`, whitened per frame by `W` and
        decorrelated for the keyframes' shared error ρ, in the span of `keep` about `shift`;
        the solution, its covariance, and the whitened and raw residuals of every used frame."""
        w = mask.astype(A.dtype)[:, None, None]
        A_m, b_m = jnp.einsum("tij,tjk->tik", W, A) * w, jnp.einsum("tij,tj->ti", W, t_rel) * w[:, :, 0]
        A_d = jax.vmap(lambda col: decorrelated(col, mask, references, ratio), in_axes=2, out_axes=2)(A_m)
        A_d, b_d = A_d.reshape(-1, 6), decorrelated(b_m, mask, references, ratio).reshape(-1)
        A_k = A_d @ keep
        x = shift + keep @ jnp.linalg.lstsq(A_k, b_d - A_d @ shift)[0]
        variance = _residual_variance((A_d @ x - b_d).reshape(-1, 3), mask, references, fitted=6)
        raw = (A.reshape(-1, 6) @ x - t_rel.reshape(-1)).reshape(-1, 3) * used[:, None]
        cov = variance * keep @ _inverse_information(A_k.T @ A_k) @ keep.T
        return x, cov, jnp.einsum("tij,tj->ti", W, raw), raw

    ratio = jnp.zeros((), A.dtype)
    W = jnp.broadcast_to(eye, A.shape[:1] + (3, 3)) / RESIDUAL_UNIT
    x, cov, white, raw = solve(ratio, used, W)
    if free_axis is not None:
        axis, free, guess = free_axis
        along = jnp.concatenate([axis, jnp.zeros(3, A.dtype)]) * free.astype(A.dtype)
        keep = jnp.eye(6, dtype=A.dtype) - jnp.outer(along, along)
        shift = (axis @ (x[:3] if guess is None else guess)) * along
        x, cov, white, raw = solve(ratio, used, W)
    if motion_cov is not None:
        W = centre_whitening(motion_cov, R_rel, x, t_ref, used)
        x, cov, white, raw = solve(ratio, used, W)
    for _ in range(shared_rounds):
        ratio = shared_variance_ratio(white, used, references)
        x, cov, white, raw = solve(ratio, used, W)
    halves = [solve(ratio, mask, W) for mask in _window_halves(times, used)]
    half_x = jnp.stack([h[0] for h in halves])
    half_var = jnp.stack([jnp.diag(h[1]) for h in halves])
    cov = cov * _split_inflation(half_x, half_var)
    if free_axis is not None:
        cov = cov + CENTRE_FREE_STD**2 * jnp.outer(along, along)
    n = 3 * jnp.sum(used)
    return x, cov, jnp.sqrt(jnp.sum(raw**2) / jnp.maximum(n, 1))


def centre_whitening(
    motion_cov: Float[Array, "T 6 6"],
    R_rel: Float[Array, "T 3 3"],
    x: Float[Array, "6"],
    t_ref: Float[Array, " T"],
    used: Bool[Array, " T"],
) -> Float[Array, "T 3 3"]:
    """Per frame, L⁻¹ with L Lᵀ = J Σ Jᵀ the covariance (m²) of `fit_centre`'s residual
    r = t_jk − (I − R_jk) c − (t_k I − t_j R_jk) v under the registration's covariance Σ
    (`motion_cov`, a left rotation vector δθ in rad, then the translation δt in m: R_jk →
    exp(δθ) R_jk, t_jk → t_jk + δt), at the solution x = (c, v): r moves by δt − [m]× δθ with
    m = R_jk (c + t_j v), so J = [−[m]×, I]. A registration error that turns the target about
    its centre at frame k (about c + t_k v) leaves r unchanged, and Σ's cross terms carry
    that; a slide leaves δθ alone and moves r in full. Frames without a finite factor get
    1 / `RESIDUAL_UNIT` (`_whitening`)."""
    m = jnp.einsum("tij,tj->ti", R_rel, x[None, :3] + t_ref[:, None] * x[None, 3:])
    skew = jax.vmap(lambda v: jnp.cross(jnp.eye(3, dtype=v.dtype), v))(m)  # row i: eᵢ × m, so [m]×
    J = jnp.concatenate([-skew, jnp.broadcast_to(jnp.eye(3, dtype=m.dtype), skew.shape)], axis=2)
    return _whitening(J @ motion_cov @ jnp.swapaxes(J, 1, 2), used)


def _whitening(rotation_cov: Float[Array, "T 3 3"], used: Bool[Array, " T"]) -> Float[Array, "T 3 3"]:
    """Per frame, L⁻¹ with L Lᵀ a residual's covariance (rad² for the rotation residuals, m²
    for the centre's, `centre_whitening`); 1 / `RESIDUAL_UNIT` where a frame is not used or its
    covariance has no finite factor."""
    eye = jnp.eye(3, dtype=rotation_cov.dtype)
    sym = (rotation_cov + jnp.swapaxes(rotation_cov, 1, 2)) / 2
    floor = 1e-12 + 1e-9 * jnp.trace(sym, axis1=1, axis2=2)
    L = jnp.linalg.cholesky(sym + floor[:, None, None] * eye[None])
    inverse = jax.vmap(lambda m: jax.scipy.linalg.solve_triangular(m, eye, lower=True))(L)
    ok = used & jnp.all(jnp.isfinite(inverse), axis=(1, 2))
    return jnp.where(ok[:, None, None], inverse, eye[None] / RESIDUAL_UNIT)


def _group_means(residuals: Float[Array, "T 3"], used: Bool[Array, " T"], references: Int[Array, " T"]):
    """Per frame: the mean residual of its keyframe's used frames, and their count."""
    r = residuals * used[:, None]
    sums = jax.ops.segment_sum(r, references, num_segments=r.shape[0])
    counts = jax.ops.segment_sum(used.astype(r.dtype), references, num_segments=r.shape[0])
    means = sums / jnp.maximum(counts, 1.0)[:, None]
    return means[references], counts[references]


def shared_variance_ratio(
    residuals: Float[Array, "T 3"], used: Bool[Array, " T"], references: Int[Array, " T"]
) -> Float[Array, ""]:
    """ρ = σ_s² / σ_w²: the variance of the error that all frames registered against one
    keyframe share (σ_s²) over that of each frame's own error (σ_w²), by moments of a fit's
    residuals. σ_w² is the spread about each keyframe's mean; a keyframe's mean residual has
    variance σ_s² + σ_w² / n for its n frames. ρ ≥ 0."""
    means, counts = _group_means(residuals, used, references)
    n_used = jnp.sum(used)
    n_groups = jnp.sum(jnp.where(used, 1.0 / jnp.maximum(counts, 1.0), 0.0))
    within = jnp.sum(((residuals - means) ** 2) * used[:, None]) / jnp.maximum(3 * (n_used - n_groups), 1.0)
    # Σ over keyframes of (|mean|²/3 − σ_w²/n), each keyframe counted once (its frames 1/n each).
    per_frame = (jnp.sum(means**2, axis=1) / 3 - within / jnp.maximum(counts, 1.0)) / jnp.maximum(counts, 1.0)
    shared = jnp.sum(jnp.where(used, per_frame, 0.0)) / jnp.maximum(n_groups, 1.0)
    return jnp.maximum(shared, 0.0) / jnp.maximum(within, jnp.finfo(residuals.dtype).tiny)


def decorrelated(
    residuals: Float[Array, "T 3"], used: Bool[Array, " T"], references: Int[Array, " T"], ratio: Float[Array, ""]
) -> Float[Array, "T 3"]:
    """The residuals whitened for a keyframe's shared error: within each keyframe's n frames
    the covariance is σ_w² (I + ρ 11ᵀ), whose inverse square root (up to 1/σ_w) is
    I − (c/n) 11ᵀ with c = 1 − 1/√(1 + nρ): each residual minus c times its keyframe's mean.

    Why: a keyframe's own range noise moves every registration against it the same way (on
    the tracked tumbles of `experiments/identify.py` that part was as large as each frame's
    own). Counted as independent, those frames pull the fit towards the keyframe's error;
    decorrelated, a keyframe's frames count for its motion's shape, not n times its offset."""
    means, counts = _group_means(residuals, used, references)
    c = 1.0 - 1.0 / jnp.sqrt(1.0 + counts * ratio)
    return jnp.where(used[:, None], residuals - c[:, None] * means, 0.0)


def _excitation(rates, ok):
    """Largest angle (rad) between a body rate's direction and their mean direction (the
    fitted model's rates: measured ones scatter with the noise)."""
    unit = rates / jnp.maximum(jnp.linalg.norm(rates, axis=1, keepdims=True), 1e-12)
    mean = jnp.sum(unit * ok[:, None], axis=0)
    mean = mean / jnp.maximum(jnp.linalg.norm(mean), 1e-12)
    angles = jnp.arccos(jnp.clip(unit @ mean, -1.0, 1.0))
    return jnp.max(jnp.where(ok, angles, 0.0))


def fixed_spin_axis(
    camera_turn: Float[Array, "T 3 3"],
    rotations: Float[Array, "T 3 3"],
    axes: Float[Array, "3 3"],
    body: Float[Array, "T 3"],
    used: Bool[Array, " T"],
) -> tuple[Float[Array, "3"], Bool[Array, ""]]:
    """The fitted motion's mean rotation axis in inertial space (unit, frame c at t = 0), and
    whether it stayed within `MIN_EXCITATION` of that mean over the used frames: the inertial
    rate Q(t)ᵀ R(t) P ω_b(t) of the model R(t) = Q A Pᵀ (`motion_rotations`; `body` its body
    rates ω_b in principal axes P = `axes`). Where it did, no motion fixes the centre of mass
    along it (`fit_centre`)."""
    spin = jnp.einsum("tji,tjk,kl,tl->ti", camera_turn, rotations, axes, body)
    unit = spin / jnp.maximum(jnp.linalg.norm(spin, axis=1, keepdims=True), 1e-12)
    mean = jnp.sum(unit * used[:, None], axis=0)
    mean = mean / jnp.maximum(jnp.linalg.norm(mean), 1e-12)
    return mean, _excitation(spin, used) < MIN_EXCITATION


def start_windows(rate_window: int, frames: int) -> tuple[int, ...]:
    """The distinct half-widths (frames) of `START_WINDOWS` × `rate_window` that fit in
    `frames` (each needs 2h + 3 frames)."""
    widest = max(1, (frames - 3) // 2)
    return tuple(sorted({min(m * rate_window, widest) for m in START_WINDOWS}))


def linear_start(times, rotations, valid, half: int, cost):
    """(axes, moments, ω at the first valid rate) from centred differences over ±`half`
    frames and conservation of momentum and energy (step 1 of the module's notes): of
    [`inertia_candidates`][], the one of least `cost(axes, moments, ω)` (the fit's own
    least-squares cost at that start; non-finite costs never chosen)."""
    rates, ok = body_rates(times, rotations, valid, half)
    omega = rates[jnp.argmax(ok)]
    axes, moments = inertia_candidates(rotations, rates, ok)
    costs = jax.vmap(lambda a, m: cost(a, m, omega))(axes, moments)
    best = jnp.argmin(jnp.where(jnp.isfinite(costs), costs, jnp.inf))
    return axes[best], moments[best], omega


def used_frames(valid: Bool[Array, " T"], references: Int[Array, " T"]) -> Bool[Array, " T"]:
    """The frames whose motion reference → frame the fit compares: valid, measured from a
    valid reference, and not a reference measured from itself."""
    return valid & valid[references] & (references != jnp.arange(valid.shape[0]))


def identify_motion(
    times: Float[Array, " T"],
    rotations: Float[Array, "T 3 3"],
    translations: Float[Array, "T 3"],
    valid: Bool[Array, " T"],
    references: Int[Array, " T"] | None = None,
    rotation_cov: Float[Array, "T 3 3"] | None = None,
    rate_window: int = 5,
    max_steps: int = 200,
    shared_rounds: int = SHARED_ROUNDS,
    orbit: Orbit | None = None,
    motion_cov: Float[Array, "T 6 6"] | None = None,
    centre_guess: Float[Array, "3"] | None = None,
) -> Dynamics:
    """Identify the dynamics from measured motions (the core of [`identify`][jaxpose.identify]).

    **Arguments:**

    - `times`: (T,) seconds since the first frame, ascending, `times[0]` = 0.
    - `rotations`, `translations`: the chained motion from the first frame to frame k,
      x ↦ R x + t (frame c, metres).
    - `valid`: frames whose motion is a measurement (frame 0 is the reference).
    - `references`: the frame each motion was measured from (a tracker's keyframe; default
      0 for every frame). The fit compares the motions reference → k, so the errors that
      chaining adds at each keyframe do not accumulate in the residuals.
    - `rotation_cov`: (T, 3, 3) covariances (rad², left rotation vector) of those motions'
      rotations, to weight the residuals (default: equal weights).
    - `rate_window`: ±frames of the centred differences of step 1 (static).
    - `max_steps`: Levenberg–Marquardt's step limit (static).
    - `shared_rounds`: refits for the keyframes' shared error after the first fit (static).
    - `orbit`: how the camera turns and the gravity gradient ([`Orbit`][jaxpose.Orbit]);
      None: a camera that holds an inertial attitude, torque-free.
    - `motion_cov`: (T, 6, 6) covariances of the whole motions (a left rotation vector in rad,
      then the translation in m), to weight the centre's residuals (`fit_centre`; default:
      equal weights).
    - `centre_guess`: (3,) a point of the target at t = 0 (m, frame c), where the centre of
      mass is taken to lie along a rotation axis that never moved (a spin about a principal
      axis, `fixed_spin_axis`), with a standard deviation of `CENTRE_FREE_STD`; default: the
      least-squares solution's.

    Pure and jittable; no checks (see `identify`).
    """
    orbit = Orbit.inertial() if orbit is None else orbit
    # Every reference array as int32 (no references: frame 0 for every frame), so that int32,
    # int64 and absent references share one compiled program.
    references = jnp.zeros(times.shape[0], jnp.int32) if references is None else jnp.asarray(references, jnp.int32)
    return _identify_motion(
        times,
        rotations,
        translations,
        valid,
        references,
        rotation_cov,
        rate_window,
        max_steps,
        shared_rounds,
        orbit,
        motion_cov,
        centre_guess,
    )


@eqx.filter_jit
def _identify_motion(
    times,
    rotations,
    translations,
    valid,
    references,
    rotation_cov,
    rate_window,
    max_steps,
    shared_rounds,
    orbit,
    motion_cov=None,
    centre_guess=None,
) -> Dynamics:
    """`identify_motion` with the orbit given (an inertial camera is `Orbit.inertial()`), so
    that both kinds of camera share one compiled program."""
    T = times.shape[0]
    used = used_frames(valid, references)
    eye = jnp.eye(3, dtype=times.dtype)
    if rotation_cov is None:
        whiten = jnp.broadcast_to(eye / RESIDUAL_UNIT, (T, 3, 3))
    else:
        whiten = _whitening(rotation_cov, used)
    tol = math.sqrt(float(jnp.finfo(times.dtype).eps))
    solver = optx.LevenbergMarquardt(rtol=tol, atol=tol)

    def solve(theta, data, ratio):
        return optx.least_squares(
            _decorrelated_residuals,
            solver,
            theta,
            (data, ratio),
            max_steps=max_steps,
            throw=False,
            options={"jac": "fwd"},
        )

    # The linear starts take the motions in frame c at t = 0 (the camera's own turn undone).
    inertial = jnp.einsum("tji,tjk->tik", orbit.camera_turn(times), rotations)

    def start_cost(axes, moments, omega):
        data = (times, rotations, used, references, whiten, axes, moments, orbit)
        theta = jnp.concatenate([jnp.zeros(5, times.dtype), omega])
        return jnp.sum(_rotation_residuals(theta, data) ** 2)

    starts = [linear_start(times, inertial, valid, h, start_cost) for h in start_windows(rate_window, T)]
    axes_s, moments_s, omega_s = (jnp.stack(part) for part in zip(*starts, strict=True))
    n_starts = len(starts)

    halves = _window_halves(times, used)
    n_rounds = n_starts + shared_rounds

    def one_fit(carry, index):
        """Round `index` < n_starts: a fit from that start, the registrations independent,
        kept when it costs less than the best so far. Then `shared_rounds` refits of the kept
        one for the keyframes' shared error. The last two rounds fit each half of the window
        alone from the kept fit and leave it as it is (`_split_inflation`). One least-squares
        program serves every round."""
        theta, axes0, moments0, cost, _, ratio_kept = carry
        first, half = index < n_starts, index >= n_rounds
        k = jnp.minimum(index, n_starts - 1)
        base_axes, base_moments = jnp.where(first, axes_s[k], axes0), jnp.where(first, moments_s[k], moments0)
        data = (times, rotations, used, references, whiten, base_axes, base_moments, orbit)
        # The start rounds fit the registrations as independent, the half rounds keep the last
        # ratio; only a refit estimates it (a switch, so that the other rounds skip its ODE solve).
        ratio = jax.lax.switch(
            jnp.where(first, 0, jnp.where(half, 1, 2)),
            [
                lambda: jnp.zeros((), times.dtype),
                lambda: ratio_kept,
                lambda: shared_variance_ratio(_rotation_residuals(theta, data), used, references),
            ],
        )
        mask = jnp.where(half, halves[jnp.clip(index - n_rounds, 0, 1)], used)
        fit_data = (times, rotations, mask, references, whiten, base_axes, base_moments, orbit)
        start = jnp.where(first, jnp.concatenate([jnp.zeros(5, times.dtype), omega_s[k]]), theta)
        sol = solve(start, fit_data, ratio)
        residuals = _rotation_residuals(sol.value, data)
        new_cost = jnp.sum(residuals**2)
        new_cost = jnp.where(jnp.isfinite(new_cost), new_cost, jnp.inf)
        new = (sol.value, base_axes, base_moments, new_cost, sol.result, ratio)
        keep_new = ~half & (~first | (new_cost < cost))
        # A half round's residual variance over its own frames (`_split_inflation`).
        scale = _residual_variance(decorrelated(residuals, mask, references, ratio), mask, references)
        return tree_select(keep_new, new, carry), (sol.value, scale)

    initial = (
        jnp.concatenate([jnp.zeros(5, times.dtype), omega_s[0]]),
        axes_s[0],
        moments_s[0],
        jnp.asarray(jnp.inf, times.dtype),
        optx.RESULTS.successful,
        jnp.zeros((), times.dtype),
    )
    (theta, axes0, moments0, _, result, ratio), (fits, scales) = jax.lax.scan(
        one_fit, initial, jnp.arange(n_rounds + 2)
    )
    data = (times, rotations, used, references, whiten, axes0, moments0, orbit)
    axes = jaxlie.SO3.exp(theta[:3]).as_matrix() @ axes0
    axes, moments = _sorted(axes, _moments(moments0, theta[3:5]))
    omega = theta[5:8]
    half_ratios = jax.vmap(lambda value: _sorted_ratios(moments0, value[3:5]))(fits[-2:])
    cov_attitude, rotation_rms, half_variances = _attitude_covariance(
        data, axes, moments, omega, ratio, halves, scales[-2:]
    )
    cov_attitude = cov_attitude * _split_inflation(half_ratios, half_variances)
    model_rotations, body = _integrate(axes, moments, omega, times, orbit)
    excitation = _excitation(body, used)
    axis, free = fixed_spin_axis(orbit.camera_turn(times), model_rotations, axes, body, used)
    centre, cov_centre, centre_rms = fit_centre(
        times, rotations, translations, used, references, shared_rounds, motion_cov, (axis, free, centre_guess)
    )
    covariance = jax.scipy.linalg.block_diag(cov_attitude, cov_centre)
    ratio_std = jnp.sqrt(jnp.maximum(jnp.diag(cov_attitude)[3:5], 0.0)) / moments[:2]
    finite = jnp.all(jnp.isfinite(covariance)) & jnp.all(jnp.isfinite(theta))
    physical = jnp.sum(moments[:2]) >= 1 - TRIANGLE_TOL
    observable = (excitation > MIN_EXCITATION) & jnp.all(ratio_std < MAX_RATIO_REL_STD) & physical & finite
    return Dynamics(
        inertia_ratios=moments[:2],
        principal_axes=axes,
        centre=centre[:3],
        velocity=centre[3:],
        omega=omega,
        covariance=covariance,
        observable=observable,
        excitation=excitation,
        rotation_rms=rotation_rms,
        centre_rms=centre_rms,
        result=result,
        frames=jnp.sum(used),
        orbit=orbit,
    )


def identify(
    track: Track,
    dt: float,
    weighted: bool = True,
    rate_window_s: float = RATE_WINDOW_S,
    max_steps: int = 200,
    orbit: Orbit | None = None,
) -> Dynamics:
    """Identify a tumbling target's dynamics from a [`jaxpose.track`][] result.

    **Arguments:**

    - `track`: what `jp.track(clouds, dt, key=...)` returns. Each frame with a successful
      registration is a measurement, keyframe → frame (`Track.keyframes`).
    - `dt`: seconds between frames.
    - `weighted`: weight each measurement by its covariance (`Track.measurement_cov`);
      False: equal weights.
    - `rate_window_s`: half-width (s) of the centred differences that start the fit.
    - `max_steps`: Levenberg–Marquardt's step limit.
    - `orbit`: for a camera fixed in the orbital frame of a circular orbit, its
      [`Orbit`][jaxpose.Orbit] (mean motion and axes): the fit then undoes the camera's
      turn and adds the gravity-gradient torque. None: a camera that holds an inertial
      attitude (a chaser holding its attitude), the target free of torque.

    **Returns:** a [`Dynamics`][jaxpose.Dynamics] in frame c at the first frame's time.

    Raises `ValueError` for a `dt` that is not a positive number, for fewer than
    `MIN_FRAMES` successful frames, or for a window too short for the rate differences.
    """
    if not isinstance(track, Track):
        raise ValueError(f"identify needs the Track that jp.track returns, got {type(track).__name__}.")
    return identify_tracked(
        track.rotations,
        track.points,
        track.registered(),
        track.keyframes,
        track.measurement_cov if weighted else None,
        dt,
        rate_window_s,
        max_steps,
        orbit=orbit,
    )


def identify_tracked(
    rotations: Float[ArrayLike, "T 3 3"],
    points: Float[ArrayLike, "T 3"],
    registered: Bool[ArrayLike, " T"],
    keyframes: Int[ArrayLike, " T"],
    measurement_cov: Float[ArrayLike, "T 6 6"] | None,
    dt: float,
    rate_window_s: float = RATE_WINDOW_S,
    max_steps: int = 200,
    shared_rounds: int = SHARED_ROUNDS,
    orbit: Orbit | None = None,
) -> Dynamics:
    """[`identify`][jaxpose.identify] on a track's arrays (`Track.rotations`, `.points`,
    `.registered()`, `.keyframes`, `.measurement_cov` or None for equal weights), so that a
    saved track can be identified again. Checks its input as `identify` does;
    `shared_rounds` and `orbit` as in `identify_motion`."""
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}.")
    rotations = jnp.asarray(rotations)
    points = jnp.asarray(points, rotations.dtype)
    T = rotations.shape[0]
    translations, finite = chained_motions(rotations, points)
    valid = jnp.asarray(registered, bool) & finite
    count = int(jnp.sum(valid))
    if count < MIN_FRAMES:
        raise ValueError(f"identify needs at least {MIN_FRAMES} successfully registered frames, got {count}.")
    half = max(1, round(rate_window_s / dt))
    if T < 2 * half + 3:
        raise ValueError(
            f"a window of {T} frames is too short for rate differences over ±{half} frames "
            f"(rate_window_s={rate_window_s} s at dt={dt} s): track longer or lower rate_window_s."
        )
    times = jnp.arange(T, dtype=rotations.dtype) * jnp.asarray(dt, rotations.dtype)
    translations = jnp.where(finite[:, None], translations, 0.0)
    rotations = jnp.where(finite[:, None, None], rotations, jnp.eye(3, dtype=rotations.dtype)[None])
    motion_cov = None if measurement_cov is None else jnp.asarray(measurement_cov, rotations.dtype)
    rotation_cov = None if motion_cov is None else motion_cov[:, :3, :3]
    references = jnp.asarray(keyframes, jnp.int32)
    return identify_motion(
        times,
        rotations,
        translations,
        valid,
        references,
        rotation_cov,
        half,
        max_steps,
        shared_rounds,
        orbit,
        motion_cov,
        points[0],
    )


__all__ = [
    "MIN_EXCITATION",
    "MAX_RATIO_REL_STD",
    "Dynamics",
    "Orbit",
    "identify",
    "identify_motion",
    "identify_tracked",
    "motion_rotations",
]
