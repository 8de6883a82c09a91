"""Tracking: keyframe-chained `estimate` results and an extended Kalman filter (issue 7).

**Chaining.** Frame k is registered against the current keyframe (the first frame, then
every `keyframe_every` frames), so the motion measured stays inside the search box and the
errors of frame-to-frame steps do not add up at every frame: only each keyframe switch adds
its pair's error. The chained motion (R_0k, t_0k) maps frame 0's points to frame k's, in the
camera frame c.

**Filter** ([`TrackFilter`][], an `eqx.Module`): the state is the target's rotation since
frame 0, A = R_0k (on SO(3), error state as a rotation vector on the left), its angular
velocity ω in frame c (rad/s; Ȧ = [ω]× A, constant-rate model with a random walk), and the
position and velocity (m, m/s) of a tracked point (frame 0's plane origin O_n, moved with
the target), constant-velocity model. Measurements: the chained (R_0k, R_0k O_n + t_0k).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float, Int, PRNGKeyArray

from .cloud import Cloud
from .config import Config
from .estimate import SUCCESS, estimate_problem
from .frame import plane_frame
from .problem import Problem


def _exp(v):
    return jaxlie.SO3.exp(v).as_matrix()


def _log(R):
    return jaxlie.SO3.from_matrix(R).log()


class TrackFilter(eqx.Module):
    """EKF state (see the module docstring): `attitude` A (3, 3), `rate` ω (3, rad/s, frame c),
    `position` (3, m, frame c), `velocity` (3, m/s), covariance `cov` (12, 12) of the error
    state (δφ, δω, δr, δv)."""

    attitude: Float[Array, "3 3"]
    rate: Float[Array, "3"]
    position: Float[Array, "3"]
    velocity: Float[Array, "3"]
    cov: Float[Array, "12 12"]

    @classmethod
    def start(cls, position, rate_sigma: float = 0.2, speed_sigma: float = 0.1) -> TrackFilter:
        """At frame 0: A = I exactly, the tracked point at `position` (m), ω and v unknown
        (zero, with standard deviations `rate_sigma` rad/s and `speed_sigma` m/s)."""
        position = jnp.asarray(position)
        var = jnp.concatenate(
            [jnp.full(3, 1e-12), jnp.full(3, rate_sigma**2), jnp.full(3, 1e-12), jnp.full(3, speed_sigma**2)]
        )
        return cls(jnp.eye(3, dtype=position.dtype), jnp.zeros(3), position, jnp.zeros(3), jnp.diag(var))

    def predict(self, dt: float, rate_noise: float, accel_noise: float) -> TrackFilter:
        """Propagate by `dt` seconds; `rate_noise` (rad/s/√s) and `accel_noise` (m/s/√s) are
        the random-walk densities of ω and v."""
        eye, zero = jnp.eye(3), jnp.zeros((3, 3))
        block = jnp.block([[eye, dt * eye], [zero, eye]])
        F = jnp.block([[block, jnp.zeros((6, 6))], [jnp.zeros((6, 6)), block]])
        q = jnp.concatenate(
            [jnp.zeros(3), jnp.full(3, rate_noise**2 * dt), jnp.zeros(3), jnp.full(3, accel_noise**2 * dt)]
        )
        return TrackFilter(
            _exp(self.rate * dt) @ self.attitude,
            self.rate,
            self.position + dt * self.velocity,
            self.velocity,
            F @ self.cov @ F.T + jnp.diag(q),
        )

    def update(self, rotation, point, noise: Float[Array, "6 6"]) -> TrackFilter:
        """Fuse a measured A (`rotation`) and tracked-point position (`point`, m) with
        covariance `noise` (rotation vector in rad, then metres)."""
        H = jnp.zeros((6, 12)).at[:3, :3].set(jnp.eye(3)).at[3:, 6:9].set(jnp.eye(3))
        residual = jnp.concatenate([_log(rotation @ self.attitude.T), point - self.position])
        S = H @ self.cov @ H.T + noise
        K = jnp.linalg.solve(S, H @ self.cov).T
        dx = K @ residual
        joseph = jnp.eye(12) - K @ H
        return TrackFilter(
            _exp(dx[:3]) @ self.attitude,
            self.rate + dx[3:6],
            self.position + dx[6:9],
            self.velocity + dx[9:],
            joseph @ self.cov @ joseph.T + K @ noise @ K.T,
        )


class Track(eqx.Module):
    """Per frame k (leading axis T): the chained measurement (`rotations` R_0k, `points`),
    the `status` of its estimate, and the filtered `attitude`, `rate` (rad/s, frame c),
    `position`, `velocity` and the filter's `rate_std` (rad/s, per axis)."""

    rotations: Float[Array, "T 3 3"]
    points: Float[Array, "T 3"]
    status: Int[Array, " T"]
    attitude: Float[Array, "T 3 3"]
    rate: Float[Array, "T 3"]
    position: Float[Array, "T 3"]
    velocity: Float[Array, "T 3"]
    rate_std: Float[Array, "T 3"]


def track(
    clouds: Cloud,
    dt: float,
    config: Config,
    key: PRNGKeyArray,
    keyframe_every: int = 25,
    rotation_sigma: float = 0.005,
    point_sigma: float = 0.005,
    rate_noise: float = 1e-4,
    accel_noise: float = 1e-4,
) -> Track:
    """Track a sequence of clouds (leading axis T, frames `dt` seconds apart).

    **Arguments:**

    - `clouds`: the frames (camera frame c, metres), e.g. `simulate_sequence(...).clouds`.
    - `config`: the estimate's [`jaxpose.Config`][] (its `max_points` must hold every frame).
    - `keyframe_every`: frames between keyframe switches (25 = 1 s at 25 Hz).
    - `rotation_sigma` (rad), `point_sigma` (m): measurement noise of a chained pose.
    - `rate_noise`, `accel_noise`: the filter's random-walk densities (see `predict`).

    Frames whose estimate is not a success are skipped by the filter (prediction only) and
    keep the last chained pose. Pure and jittable (`lax.scan` over frames).
    """
    first = jax.tree.map(lambda x: x[0], clouds)
    frame0 = plane_frame(first)  # O_n of frame 0: the tracked point
    noise = jnp.diag(jnp.concatenate([jnp.full(3, rotation_sigma**2), jnp.full(3, point_sigma**2)]))
    eye = jnp.eye(3, dtype=frame0.origin.dtype)

    def step(carry, inputs):
        key_cloud, key_R, key_t, last_R, last_t, filt = carry
        k, cloud = inputs
        problem = Problem.build(key_cloud, cloud, config)
        est = estimate_problem(problem, config, jax.random.fold_in(key, k))
        ok = est.status == SUCCESS
        R = jnp.where(ok, est.rotation @ key_R, last_R)  # chain: frame 0 → keyframe → k
        t = jnp.where(ok, est.rotation @ key_t + est.translation, last_t)
        point = R @ frame0.origin + t
        filt = filt.predict(dt, rate_noise, accel_noise)
        updated = filt.update(R, point, noise)
        filt = jax.tree.map(lambda a, b: jnp.where(ok, a, b), updated, filt)
        switch = (k % keyframe_every == 0) & ok
        key_cloud = jax.tree.map(lambda a, b: jnp.where(switch, a, b), cloud, key_cloud)
        key_R, key_t = jnp.where(switch, R, key_R), jnp.where(switch, t, key_t)
        out = (R, point, est.status, filt.attitude, filt.rate, filt.position, filt.velocity)
        return (key_cloud, key_R, key_t, R, t, filt), (*out, jnp.sqrt(jnp.diag(filt.cov)[3:6]))

    zeros = jnp.zeros(3, eye.dtype)
    filt = TrackFilter.start(frame0.origin)
    carry = (first, eye, zeros, eye, zeros, filt)
    frames = jnp.arange(1, clouds.valid.shape[0])
    rest = jax.tree.map(lambda x: x[1:], clouds)
    _, outs = jax.lax.scan(step, carry, (frames, rest))
    head = (eye, frame0.origin, jnp.asarray(SUCCESS), filt.attitude, filt.rate, filt.position, filt.velocity)
    head = (*head, jnp.sqrt(jnp.diag(filt.cov)[3:6]))
    return Track(*(jnp.concatenate([jnp.asarray(h)[None], o]) for h, o in zip(head, outs, strict=True)))


__all__ = ["Track", "TrackFilter", "track"]
