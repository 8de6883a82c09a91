"""Lidar sequences of a tumbling target: dynamics (diffrax) → poses → clouds (issue 7).

The chaser flies the chief's orbit and holds its camera fixed in the orbital frame o, with
the optical axis z_c along the in-track axis x_o: camera axes (x_c, y_c, z_c) = (y_o, z_o,
x_o), a right-handed triad, so "down" in the image is radially outward. The target's centre O_t moves relative to
the chief under Clohessy–Wiltshire; its attitude follows Euler's equations with the
gravity-gradient torque ([`jaxpose.dynamics`][]). Positions in metres, rates in rad/s, times
in seconds.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float, PRNGKeyArray

from .._cloud import Cloud
from ._camera import Camera
from ._dynamics import propagate_attitude, propagate_cw, quat_to_matrix
from ._scenarios import paper_pose
from ._simulate import simulate
from .targets import CHIBIS_M_INERTIA

C_FROM_O = jnp.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""Rows: camera axes in orbital-frame coordinates (x_c = y_o, y_c = z_o, z_c = x_o)."""


class Tumble(eqx.Module):
    """Initial state of a tumbling target.

    **Fields:**

    - `position`, `velocity`: O_t relative to the chief in the camera frame c at t = 0 (m,
      m/s); converted to the orbital frame o for the CW dynamics.
    - `attitude`: G^c_t at t = 0 (target → camera), a rotation matrix.
    - `rate`: the target's angular velocity in its body axes (rad/s).
    - `inertia`: its inertia tensor in body axes (kg·m²).
    - `orbit_rate`: mean motion of the chief's circular orbit (rad/s).
    """

    position: Float[Array, "3"]
    velocity: Float[Array, "3"]
    attitude: Float[Array, "3 3"]
    rate: Float[Array, "3"]
    inertia: Float[Array, "3 3"]
    orbit_rate: float

    @classmethod
    def n5(cls, rate_deg_s: float = 4.5, distance: float = 5.5, key: PRNGKeyArray | None = None) -> Tumble:
        """N5 at `distance` m on the optical axis in the paper's previous attitude, tumbling at
        `rate_deg_s` °/s about a fixed body direction (random with `key`, else (1, 2, 3)/√14),
        at rest relative to the chief, 500 km orbit; inertia of a 1.6 × 1.0 × 0.8 m 100 kg box
        (N5's body; the panels are thin)."""
        axis = jnp.array([1.0, 2.0, 3.0]) if key is None else jax.random.normal(key, (3,))
        mass, (a, b, c) = 100.0, (1.6, 1.0, 0.8)
        inertia = jnp.diag(jnp.array([b * b + c * c, a * a + c * c, a * a + b * b]) * mass / 12)
        return cls(
            position=jnp.array([0.0, 0.0, distance]),
            velocity=jnp.zeros(3),
            attitude=paper_pose("previous")[0],
            rate=math.radians(rate_deg_s) * axis / jnp.linalg.norm(axis),
            inertia=inertia,
            orbit_rate=orbit_rate(500e3),
        )

    @classmethod
    def random(
        cls,
        key: PRNGKeyArray,
        distance: float = 5.5,
        rates_deg_s: tuple[float, float] = (0.5, 10.0),
        orbital_camera: bool = False,
        mass: float = 100.0,
    ) -> Tumble:
        """A random tumble: a uniformly random attitude and rotation axis, a rate drawn
        uniformly from `rates_deg_s` (°/s), principal moments of inertia with random ratios
        (the two smaller ones 1–2.5 × a unit, the largest between the larger of them and
        their sum, so every ratio is a rigid body's; times `mass` kg·m²), the target at
        `distance` m on the optical axis, ±0.2 m across it, at rest relative to the chief.

        `orbital_camera` False: torque-free motion seen by a camera holding an inertial
        attitude (no orbit). True: gravity-gradient torque of a 500 km orbit, the camera fixed
        in the orbital frame."""
        keys = jax.random.split(key, 6)
        small = jax.random.uniform(keys[0], (2,), minval=1.0, maxval=2.5)
        largest = jax.random.uniform(keys[1], minval=jnp.max(small), maxval=jnp.sum(small))
        moments = jnp.concatenate([small, largest[None]])
        axis = jax.random.normal(keys[2], (3,))
        rate = jnp.radians(jax.random.uniform(keys[3], minval=rates_deg_s[0], maxval=rates_deg_s[1]))
        offset = jax.random.uniform(keys[5], (2,), minval=-0.2, maxval=0.2)
        return cls(
            position=jnp.concatenate([offset, jnp.array([distance])]),
            velocity=jnp.zeros(3),
            attitude=jaxlie.SO3.sample_uniform(keys[4]).as_matrix(),
            rate=rate * axis / jnp.linalg.norm(axis),
            inertia=jnp.diag(moments * mass / 2.5),
            orbit_rate=orbit_rate(500e3) if orbital_camera else 0.0,
        )

    @classmethod
    def chibis_m(cls, rate_deg_s: float | None = None) -> Tumble:
        """The Chibis-M separation scenario (RELATED.md A.7), read in the camera frame c as
        the report presumably meant (3 m along the optical axis): O_t at (0, 0, 3) m moving
        at (0, 0, 0.01) m/s, body rate (0, 0.01, 0) rad/s, inertia diag(1.60, 1.16, 1.86)
        kg·m², circular orbit of 600 km (as printed; the Progress TLE implies ≈ 500 km).
        Initial attitude: the paper's previous attitude (23.5°, 23.5°, 1°), ours.

        `rate_deg_s` replaces the rate by one of that magnitude about the report's measured
        axis ω ∝ (2.08, 3.01, 2.15) (its flight video: |ω| = 4.24 °/s; rate sensors 4.5 °/s).
        """
        if rate_deg_s is None:
            rate = jnp.array([0.0, 0.01, 0.0])
        else:
            axis = jnp.array([2.08, 3.01, 2.15])
            rate = math.radians(rate_deg_s) * axis / jnp.linalg.norm(axis)
        return cls(
            position=jnp.array([0.0, 0.0, 3.0]),
            velocity=jnp.array([0.0, 0.0, 0.01]),
            attitude=paper_pose("previous")[0],
            rate=rate,
            inertia=jnp.diag(jnp.asarray(CHIBIS_M_INERTIA)),
            orbit_rate=orbit_rate(600e3),
        )


def orbit_rate(altitude: float) -> float:
    """Mean motion (rad/s) of a circular Earth orbit at `altitude` metres."""
    mu, radius = 3.986004418e14, 6378137.0
    return math.sqrt(mu / (radius + altitude) ** 3)


class Sequence(eqx.Module):
    """A simulated sequence: `times` (T,) s, true poses `rotations` (T, 3, 3) = G^c_t and
    `positions` (T, 3) m of O_t in frame c, body `rates` (T, 3) rad/s, and the clouds (a
    [`jaxpose.Cloud`][] with a leading axis T)."""

    times: Float[Array, " T"]
    rotations: Float[Array, "T 3 3"]
    positions: Float[Array, "T 3"]
    rates: Float[Array, "T 3"]
    clouds: Cloud


def tumble_poses(tumble: Tumble, times: Float[Array, " T"]):
    """True poses of the target at `times` (s from the initial state): G^c_t (T, 3, 3), O_t in
    frame c (T, 3) and the body rates (T, 3)."""
    times = jnp.asarray(times)
    # The integrators start at their first time: prepend t = 0 (the initial state), drop it after.
    grid = jnp.concatenate([jnp.zeros(1, times.dtype), times])
    w = tumble.orbit_rate
    # Orbital frame o at time t relative to the inertial frame i (= o at t = 0): o turns about
    # +y at the orbit rate, so vectors in i map to o by R_y(ω t)ᵀ.
    state0 = jnp.concatenate([C_FROM_O.T @ tumble.position, C_FROM_O.T @ tumble.velocity])
    rel = propagate_cw(state0, w, grid)[1:]
    positions = rel[:, :3] @ C_FROM_O.T
    # Attitude: body → inertial from the quaternion, inertial → orbital, orbital → camera.
    body_to_i0 = C_FROM_O.T @ tumble.attitude  # at t = 0, i = o
    q0 = jaxlie.SO3.from_matrix(body_to_i0).wxyz
    q, rates = propagate_attitude(q0, tumble.rate, tumble.inertia, w, grid)
    q, rates = q[1:], rates[1:]

    def camera_attitude(t, qk):
        c, s = jnp.cos(w * t), jnp.sin(w * t)
        o_from_i = jnp.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
        return C_FROM_O @ o_from_i @ quat_to_matrix(qk)

    return jax.vmap(camera_attitude)(times, q), positions, rates


def simulate_sequence(
    camera: Camera, target, tumble: Tumble, duration: float, rate_hz: float = 25.0, key: PRNGKeyArray | None = None
) -> Sequence:
    """Frames at `rate_hz` (default 25 Hz, the ToF camera) over `duration` seconds.

    **Returns:** a [`Sequence`][jaxpose.sim.Sequence]; frame k is taken at t = k / rate_hz. Noise and dropout
    come from the camera and need `key` (one subkey per frame), as in [`jaxpose.simulate`][].
    """
    times = jnp.arange(int(round(duration * rate_hz)) + 1) / rate_hz
    rotations, positions, rates = tumble_poses(tumble, times)
    if key is None:
        clouds = jax.vmap(lambda R, t: simulate(camera, target, R, t))(rotations, positions)
    else:
        keys = jax.random.split(key, times.shape[0])
        clouds = jax.vmap(lambda R, t, k: simulate(camera, target, R, t, k))(rotations, positions, keys)
    return Sequence(times, rotations, positions, rates, clouds)


__all__ = ["C_FROM_O", "Sequence", "Tumble", "orbit_rate", "simulate_sequence", "tumble_poses"]
