"""Relative orbital and attitude dynamics of the target (RELATED.md §A.1, §A.5), integrated
with diffrax.

**Orbital frame o** (Clohessy–Wiltshire axes, RELATED.md): z radially outward, x along the
track, y completing the right-handed triad (the orbit normal). The chief is on a circular
orbit with angular rate ω (rad/s); the frame o turns about +y at ω. Positions in metres,
velocities in m/s, times in seconds.

**Attitude**: unit quaternion q = (w, x, y, z) of the body frame b relative to the inertial
frame i that coincides with o at t = 0 (R(q) maps body vectors to frame i); ω is the
absolute angular velocity in body axes (rad/s); J the inertia tensor in body axes (kg·m²).
"""

from __future__ import annotations

import diffrax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float


def cw_rhs(t, state: Float[Array, "6"], omega) -> Float[Array, "6"]:
    """Clohessy–Wiltshire: ẍ = −2ω ż, ÿ = −ω² y, z̈ = 2ω ẋ + 3ω² z; state (x, y, z, ẋ, ẏ, ż)."""
    x, y, z, vx, vy, vz = state
    return jnp.stack([vx, vy, vz, -2 * omega * vz, -(omega**2) * y, 2 * omega * vx + 3 * omega**2 * z])


def cw_closed_form(t, state0: Float[Array, "6"], omega) -> Float[Array, "6"]:
    """The closed-form CW solution (RELATED.md §A.1, constants C1…C6), state at time t."""
    x0, y0, z0, vx0, vy0, vz0 = state0
    c1 = 2 * z0 + vx0 / omega
    c2 = vz0 / omega
    c3 = -3 * z0 - 2 * vx0 / omega
    c4 = x0 - 2 * vz0 / omega
    c5, c6 = vy0 / omega, y0
    s, c = jnp.sin(omega * t), jnp.cos(omega * t)
    return jnp.stack(
        [
            c4 - 3 * c1 * omega * t + 2 * c2 * c - 2 * c3 * s,
            c5 * s + c6 * c,
            2 * c1 + c2 * s + c3 * c,
            -3 * c1 * omega - 2 * c2 * omega * s - 2 * c3 * omega * c,
            c5 * omega * c - c6 * omega * s,
            c2 * omega * c - c3 * omega * s,
        ]
    )


def quat_to_matrix(q: Float[Array, "4"]) -> Float[Array, "3 3"]:
    """Rotation matrix of a quaternion (w, x, y, z), normalised first: body → inertial."""
    return jaxlie.SO3(wxyz=q / jnp.linalg.norm(q)).as_matrix()


def local_vertical(t, omega) -> Float[Array, "3"]:
    """e3 of the orbital frame o (radially outward) in the inertial frame i at time t: o
    turns about +y at ω, so e3(t) = R_y(ωt) e3."""
    return jnp.stack([jnp.sin(omega * t), jnp.zeros_like(t), jnp.cos(omega * t)])


def attitude_rhs(t, state: Float[Array, "7"], args) -> Float[Array, "7"]:
    """Euler's equations with the gravity-gradient torque (RELATED.md (2.6)) and quaternion
    kinematics q̇ = ½ q ⊗ (0, ω). state = (q (4), ω (3)); args = (J (3, 3), ω0 orbital rate)."""
    J, omega0 = args
    q, w = state[:4], state[4:]
    e3 = quat_to_matrix(q).T @ local_vertical(t, omega0)  # local vertical in body axes
    torque = 3 * omega0**2 * jnp.cross(e3, J @ e3)
    w_dot = jnp.linalg.solve(J, torque - jnp.cross(w, J @ w))
    # jaxlie's SO3 product is the Hamilton product of the raw wxyz arrays, so it also serves
    # the pure quaternion (0, ω) of the kinematics.
    q_dot = 0.5 * (jaxlie.SO3(wxyz=q) @ jaxlie.SO3(wxyz=jnp.concatenate([jnp.zeros(1, w.dtype), w]))).wxyz
    return jnp.concatenate([q_dot, w_dot])


def _solve(rhs, y0, ts, args, rtol, atol):
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(rhs),
        diffrax.Dopri8(),
        t0=ts[0],
        t1=ts[-1],
        dt0=None,
        y0=y0,
        args=args,
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        max_steps=1_000_000,
    )
    return sol.ys


def propagate_cw(state0: Float[Array, "6"], omega, ts: Float[Array, " T"], rtol=1e-12, atol=1e-12):
    """CW relative state at the times `ts` (s, ts[0] is the time of `state0`), integrated with
    diffrax (Dopri8, adaptive). **Returns:** `(T, 6)` states (m, m/s) in the orbital frame."""
    return _solve(cw_rhs, jnp.asarray(state0), jnp.asarray(ts), omega, rtol, atol)


def propagate_attitude(q0, w0, J, omega0, ts, rtol=1e-10, atol=1e-12):
    """Attitude (q, ω) at the times `ts` under the gravity-gradient torque (ω0 = 0: torque
    free). **Returns:** `(T, 4)` unit quaternions (body → inertial) and `(T, 3)` body rates
    (rad/s); the quaternions are renormalised after integration."""
    y0 = jnp.concatenate([jnp.asarray(q0), jnp.asarray(w0)])
    ys = _solve(attitude_rhs, y0, jnp.asarray(ts), (jnp.asarray(J), omega0), rtol, atol)
    q = ys[:, :4] / jnp.linalg.norm(ys[:, :4], axis=1, keepdims=True)
    return q, ys[:, 4:]


__all__ = [
    "attitude_rhs",
    "cw_closed_form",
    "cw_rhs",
    "local_vertical",
    "propagate_attitude",
    "propagate_cw",
    "quat_to_matrix",
]
