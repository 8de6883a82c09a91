"""Identification of a tumbling target's dynamics from a tracked motion history.

A rigid body free of torque keeps its angular momentum, so its next tens of seconds are
fixed by its principal axes, its two inertia ratios, its angular velocity at one instant and
the path of its centre of mass. [`identify`][jaxpose.identify] estimates all of them from the
motions that [`jaxpose.track`][] measures, and [`Dynamics.predict`][jaxpose.Dynamics.predict]
carries them past the data.

**Frames and conventions.** Frame c is the camera frame, taken as inertial: a chaser that
holds its attitude, and no orbital dynamics over the window. The measured motion from the
first frame to frame k is x ↦ R_k x + t_k in frame c (metres). The body's principal frame b
has its axes along the columns of P (frame c at the first frame's time), ordered so that
J1 ≤ J2 ≤ J3. Its attitude A(t) maps frame b to frame c, with A(0) = P. Then
R(t) = A(t) Pᵀ, and Euler's equations J ω̇ = −ω × Jω hold for the body rate ω in frame b.

**Fit, in three steps:**

1. *Initial inertia, linear.* The rate u_k = log(R_{k−h}ᵀ R_{k+h}) / (t_{k+h} − t_{k−h})
   is the body rate in the first frame's axes (centred differences over ±h frames). The
   angular momentum R_k M u_k and the energy u_kᵀ M u_k are constant for the inertia tensor
   M = P J Pᵀ expressed in those axes. Both are linear in M's six entries, so M comes from
   the smallest singular vector of the stacked deviations from their means. Its eigenvectors
   give P and its eigenvalues the ratios.
2. *Attitude, nonlinear.* optimistix Levenberg–Marquardt over the axes (a rotation vector
   on the left of P), the two ratios (as logarithms) and the first frame's rate in frame c.
   The residuals compare each measured motion keyframe j → k (a tracker registers frame k
   against keyframe j) with the model's R(t_k) R(t_j)ᵀ, as a left rotation vector whitened by
   the measurement's covariance. Comparing the chained R_0k instead would count every
   keyframe's error again in all later frames. R(t) is integrated by diffrax through Euler's
   equations and the quaternion kinematics (forward-mode differentiable).
3. *Centre of mass, linear.* A point that the body turns about moves on a straight line,
   c + v t, so each motion j → k maps c + t_j v to c + t_k v:
   t_jk = (I − R_jk) c + (t_k I − t_j R_jk) v, linear in (c, v), solved by least squares.

**Uncertainty and observability.** Each block's covariance is σ̂² (JᵀJ)⁻¹ at the solution,
with σ̂² the whitened residuals' variance (1 when the measurement covariances are right),
times a design effect: the frames registered against one keyframe share that keyframe's
noise, so their residuals move together and count as fewer independent ones. The
eigenvalues of JᵀJ are floored, so that a direction the data leave free gets a huge
variance, not none. A spin about a principal axis leaves the ratios unobservable: the body
rate's direction does not move. `observable` is False when the fitted body rate's direction
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

from ._track import Track

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

RESIDUAL_UNIT = 1e-3
"""Rotation residuals are scaled to milliradians inside the least squares (conditioning)."""


class Dynamics(eqx.Module):
    """A tumbling target's identified dynamics (torque-free; camera frame c taken as inertial).

    **Fields** (frame c at the first frame's time t = 0):

    - `inertia_ratios`: (J1/J3, J2/J3), with J1 ≤ J2 ≤ J3.
    - `principal_axes`: (3, 3); column i is the axis of J_i (a rotation matrix).
    - `centre`: the centre of mass (m).
    - `velocity`: the centre of mass's velocity (m/s).
    - `omega`: the angular velocity at t = 0 (rad/s).
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
        R = motion_rotations(self.principal_axes, self.moments, self.omega, times)
        t = self.centre[None] + times[:, None] * self.velocity[None] - R @ self.centre
        return R, t

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
            R = motion_rotations(axes, moments, theta[5:8], times)
            centre, velocity = theta[8:11], theta[11:14]
            return R @ (point - centre) + centre[None] + times[:, None] * velocity[None]

        theta = jnp.concatenate(
            [jnp.zeros(3, point.dtype), self.inertia_ratios, self.omega, self.centre, self.velocity]
        )
        positions = path(theta)
        jac = jax.jacfwd(path)(theta)  # (T, 3, 14)
        var = jnp.einsum("tip,pq,tiq->ti", jac, self.covariance, jac)
        return positions, jnp.sqrt(jnp.maximum(var, 0.0))


def euler_rhs(t, state: Float[Array, "7"], moments: Float[Array, "3"]) -> Float[Array, "7"]:
    """Torque-free Euler's equations in principal axes and the quaternion kinematics
    q̇ = ½ q ⊗ (0, ω). state = (q (4, wxyz, body b → frame c), ω (3, rad/s, frame b))."""
    q, w = state[:4], state[4:]
    w_dot = -jnp.cross(w, moments * w) / moments
    pure = jnp.concatenate([jnp.zeros(1, w.dtype), w])
    q_dot = 0.5 * (jaxlie.SO3(wxyz=q) @ jaxlie.SO3(wxyz=pure)).wxyz
    return jnp.concatenate([q_dot, w_dot])


def motion_rotations(
    axes: Float[Array, "3 3"], moments: Float[Array, "3"], omega: Float[Array, "3"], times: Float[Array, " T"]
) -> Float[Array, "T 3 3"]:
    """R(t) = A(t) Pᵀ at `times` (s ≥ 0, ascending) for principal axes P = `axes` (frame c),
    moments (J1, J2, J3) up to scale and the rate `omega` at t = 0 (rad/s, frame c).
    diffrax (Tsit5, adaptive), forward-mode differentiable."""
    return _integrate(axes, moments, omega, times)[0]


def _integrate(axes, moments, omega, times) -> tuple[Float[Array, "T 3 3"], Float[Array, "T 3"]]:
    """`motion_rotations` and the body rates ω(t) (rad/s, principal axes) at `times`."""
    dtype = omega.dtype
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
        args=moments,
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
    return jnp.where(solved, A @ axes.T, jnp.eye(3, dtype=dtype)[None]), rates


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


def initial_inertia(
    rotations: Float[Array, "T 3 3"], rates: Float[Array, "T 3"], ok: Bool[Array, " T"]
) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """Principal axes P (frame c at t = 0, det +1) and moments (J1 ≤ J2 ≤ J3, divided by J3)
    from conservation of angular momentum and energy (step 1 of the module's notes)."""
    rows = jax.vmap(_momentum_rows)(rotations, rates)  # (T, 4, 6)
    w = ok.astype(rows.dtype)[:, None, None]
    mean = jnp.sum(rows * w, axis=0) / jnp.maximum(jnp.sum(w), 1.0)
    dev = ((rows - mean[None]) * w).reshape(-1, 6)
    _, _, vt = jnp.linalg.svd(dev, full_matrices=False)
    m = vt[-1]
    M = jnp.array([[m[0], m[3], m[4]], [m[3], m[1], m[5]], [m[4], m[5], m[2]]])
    M = M * jnp.sign(jnp.trace(M) + 1e-30)
    evals, evecs = jnp.linalg.eigh(M)
    evals = jnp.maximum(evals, MIN_MOMENT * evals[2])
    return _right_handed(evecs), evals / evals[2]


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
    times, rotations, used, references, whiten, base_axes, base_moments = data
    axes = jaxlie.SO3.exp(theta[:3]).as_matrix() @ base_axes
    moments = _moments(base_moments, theta[3:5])
    R = motion_rotations(axes, moments, theta[5:8], times)
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


def _attitude_covariance(data, axes, moments, omega):
    """Covariance over (δaxes (3), ratios (2), ω (3)) at the sorted solution: σ̂² (JᵀJ)⁻¹ over
    the whitened residuals (σ̂² their variance: 1 when the measurement covariances are right),
    times the residuals' `_design_effect`; and the RMS of the unwhitened rotation residuals
    (rad)."""
    times, rotations, used, references, whiten, _, _ = data

    def residuals(phi, weights):
        full = jnp.concatenate([phi[3:5], jnp.ones(1, phi.dtype)])
        base = jaxlie.SO3.exp(phi[:3]).as_matrix() @ axes
        theta = jnp.concatenate([jnp.zeros(5, phi.dtype), phi[5:8]])
        return _rotation_residuals(theta, (times, rotations, used, references, weights, base, full)).reshape(-1)

    phi = jnp.concatenate([jnp.zeros(3, omega.dtype), moments[:2], omega])
    r = residuals(phi, whiten)
    jac = jax.jacfwd(residuals)(phi, whiten)
    n = 3 * jnp.sum(used)
    variance = jnp.sum(r**2) / jnp.maximum(n - 8, 1) * _design_effect(r.reshape(-1, 3), used, references)
    raw = residuals(phi, jnp.broadcast_to(jnp.eye(3, dtype=omega.dtype), whiten.shape))
    return variance * _inverse_information(jac.T @ jac), jnp.sqrt(jnp.sum(raw**2) / jnp.maximum(n, 1))


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
) -> tuple[Float[Array, "6"], Float[Array, "6 6"], Float[Array, ""]]:
    """(c, v) by least squares over the measured motions keyframe j → k (step 3): the centre
    moves from c + t_j v to c + t_k v, so t_jk = (I − R_jk) c + (t_k I − t_j R_jk) v. Also its
    covariance σ̂² (AᵀA)⁻¹ times the residuals' `_design_effect`, and their RMS (m)."""
    eye = jnp.eye(3, dtype=rotations.dtype)
    R_rel = jnp.einsum("tij,tkj->tik", rotations, rotations[references])
    t_rel = translations - jnp.einsum("tij,tj->ti", R_rel, translations[references])
    t_ref = times[references]
    A = jnp.concatenate([eye[None] - R_rel, times[:, None, None] * eye[None] - t_ref[:, None, None] * R_rel], axis=2)
    w = used.astype(A.dtype)[:, None, None]
    A, b = (A * w).reshape(-1, 6), (t_rel[:, :, None] * w).reshape(-1)
    normal = _inverse_information(A.T @ A)
    x = jnp.linalg.lstsq(A, b)[0]
    r = A @ x - b
    n = 3 * jnp.sum(used)
    variance = jnp.sum(r**2) / jnp.maximum(n - 6, 1) * _design_effect(r.reshape(-1, 3), used, references)
    return x, variance * normal, jnp.sqrt(jnp.sum(r**2) / jnp.maximum(n, 1))


def _whitening(rotation_cov: Float[Array, "T 3 3"], used: Bool[Array, " T"]) -> Float[Array, "T 3 3"]:
    """Per frame, L⁻¹ with L Lᵀ the rotation covariance (rad²); 1 / `RESIDUAL_UNIT` where a
    frame is not used or its covariance has no finite factor."""
    eye = jnp.eye(3, dtype=rotation_cov.dtype)
    sym = (rotation_cov + jnp.swapaxes(rotation_cov, 1, 2)) / 2
    floor = 1e-12 + 1e-9 * jnp.trace(sym, axis1=1, axis2=2)
    L = jnp.linalg.cholesky(sym + floor[:, None, None] * eye[None])
    inverse = jax.vmap(lambda m: jax.scipy.linalg.solve_triangular(m, eye, lower=True))(L)
    ok = used & jnp.all(jnp.isfinite(inverse), axis=(1, 2))
    return jnp.where(ok[:, None, None], inverse, eye[None] / RESIDUAL_UNIT)


def _excitation(rates, ok):
    """Largest angle (rad) between a body rate's direction and their mean direction (the
    fitted model's rates: measured ones scatter with the noise)."""
    unit = rates / jnp.maximum(jnp.linalg.norm(rates, axis=1, keepdims=True), 1e-12)
    mean = jnp.sum(unit * ok[:, None], axis=0)
    mean = mean / jnp.maximum(jnp.linalg.norm(mean), 1e-12)
    angles = jnp.arccos(jnp.clip(unit @ mean, -1.0, 1.0))
    return jnp.max(jnp.where(ok, angles, 0.0))


@eqx.filter_jit
def identify_motion(
    times: Float[Array, " T"],
    rotations: Float[Array, "T 3 3"],
    translations: Float[Array, "T 3"],
    valid: Bool[Array, " T"],
    references: Int[Array, " T"] | None = None,
    rotation_cov: Float[Array, "T 3 3"] | None = None,
    rate_window: int = 5,
    max_steps: int = 200,
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

    Pure and jittable; no checks (see `identify`).
    """
    T = times.shape[0]
    references = jnp.zeros(T, jnp.int32) if references is None else references
    used = valid & valid[references] & (references != jnp.arange(T))
    eye = jnp.eye(3, dtype=times.dtype)
    if rotation_cov is None:
        whiten = jnp.broadcast_to(eye / RESIDUAL_UNIT, (T, 3, 3))
    else:
        whiten = _whitening(rotation_cov, used)
    rates, ok = body_rates(times, rotations, valid, rate_window)
    axes0, moments0 = initial_inertia(rotations, rates, ok)
    omega0 = rates[jnp.argmax(ok)]
    data = (times, rotations, used, references, whiten, axes0, moments0)
    tol = math.sqrt(float(jnp.finfo(times.dtype).eps))
    solver = optx.LevenbergMarquardt(rtol=tol, atol=tol)
    theta0 = jnp.concatenate([jnp.zeros(5, times.dtype), omega0])
    sol = optx.least_squares(
        _rotation_residuals, solver, theta0, data, max_steps=max_steps, throw=False, options={"jac": "fwd"}
    )
    theta = sol.value
    axes = jaxlie.SO3.exp(theta[:3]).as_matrix() @ axes0
    axes, moments = _sorted(axes, _moments(moments0, theta[3:5]))
    omega = theta[5:8]
    cov_attitude, rotation_rms = _attitude_covariance(data, axes, moments, omega)
    centre, cov_centre, centre_rms = fit_centre(times, rotations, translations, used, references)
    covariance = jax.scipy.linalg.block_diag(cov_attitude, cov_centre)
    excitation = _excitation(_integrate(axes, moments, omega, times)[1], used)
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
        result=sol.result,
        frames=jnp.sum(used),
    )


def identify(
    track: Track, dt: float, weighted: bool = True, rate_window_s: float = RATE_WINDOW_S, max_steps: int = 200
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

    **Returns:** a [`Dynamics`][jaxpose.Dynamics] in frame c at the first frame's time. The camera is
    taken as inertial over the window (a chaser holding its attitude) and the target free of
    torque.

    Raises `ValueError` for a `dt` that is not a positive number, for fewer than
    `MIN_FRAMES` successful frames, or for a window too short for the rate differences.
    """
    if not isinstance(track, Track):
        raise ValueError(f"identify needs the Track that jp.track returns, got {type(track).__name__}.")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}.")
    rotations = jnp.asarray(track.rotations)
    T = rotations.shape[0]
    translations = track.points - jnp.einsum("tij,j->ti", rotations, track.points[0])
    finite = jnp.all(jnp.isfinite(rotations), axis=(1, 2)) & jnp.all(jnp.isfinite(translations), axis=1)
    valid = track.registered() & finite
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
    rotation_cov = jnp.asarray(track.measurement_cov)[:, :3, :3] if weighted else None
    references = jnp.asarray(track.keyframes, jnp.int32)
    return identify_motion(times, rotations, translations, valid, references, rotation_cov, half, max_steps)


__all__ = ["MIN_EXCITATION", "MAX_RATIO_REL_STD", "Dynamics", "identify", "identify_motion", "motion_rotations"]
