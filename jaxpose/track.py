"""Tracking: keyframe-chained `estimate` results and an extended Kalman filter (issue 7).

Two pure steps, also usable on their own: [`chain_estimates`][] registers every frame and
chains the motions, [`filter_chain`][] runs the filter over the chained measurements (cheap,
so a filter can be tuned on one set of registrations); [`track`][] is both.

**Chaining.** Frame k is registered against the current keyframe (the first frame, then
every `keyframe_every` frames), so the motion measured stays inside the search box and the
errors of frame-to-frame steps do not add up at every frame: only each keyframe switch adds
its pair's error. The chained motion (R_0k, t_0k) maps frame 0's points to frame k's, in the
camera frame c.

**Filter** ([`TrackFilter`][], an `eqx.Module`): the state is the target's rotation since
frame 0, A = R_0k (on SO(3), error state as a rotation vector on the left), its angular
velocity ω and angular acceleration α in frame c (rad/s, rad/s²), and the position and
velocity (m, m/s) of a tracked point (frame 0's plane origin O_n, moved with the target).
Why α: a body tumbling about a non-principal axis keeps its angular momentum, not its
angular velocity; for N5 at 4.5 °/s the apparent ω drifts by ≈ 0.06 °/s per second, which a
constant-rate model follows only with a lag (measured: 0.25 °/s error after 10 s). The
shape, hence the inertia, is unknown, so Euler's equations cannot be used; a
constant-acceleration model with a random walk on α follows a smooth drift without lag.
Measurements: the chained (R_0k, R_0k O_n + t_0k).
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
    `spin_accel` α (3, rad/s², frame c), `position` (3, m, frame c), `velocity` (3, m/s),
    covariance `cov` (15, 15) of the error state (δφ, δω, δα, δr, δv)."""

    attitude: Float[Array, "3 3"]
    rate: Float[Array, "3"]
    spin_accel: Float[Array, "3"]
    position: Float[Array, "3"]
    velocity: Float[Array, "3"]
    cov: Float[Array, "15 15"]

    @classmethod
    def start(
        cls, position, rate_sigma: float = 0.2, spin_accel_sigma: float = 0.01, speed_sigma: float = 0.1
    ) -> TrackFilter:
        """At frame 0: A = I exactly, the tracked point at `position` (m), ω, α and v unknown
        (zero, with standard deviations `rate_sigma` rad/s, `spin_accel_sigma` rad/s² and
        `speed_sigma` m/s)."""
        position = jnp.asarray(position)
        sigmas = (1e-6, rate_sigma, spin_accel_sigma, 1e-6, speed_sigma)
        var = jnp.concatenate([jnp.full(3, s**2) for s in sigmas])
        zero = jnp.zeros(3, position.dtype)
        return cls(jnp.eye(3, dtype=position.dtype), zero, zero, position, zero, jnp.diag(var))

    def predict(self, dt: float, rate_noise: float, accel_noise: float, spin_accel_noise: float = 0.0) -> TrackFilter:
        """Propagate by `dt` seconds. Random-walk densities: `rate_noise` on ω (rad/s/√s),
        `spin_accel_noise` on α (rad/s²/√s), `accel_noise` on v (m/s/√s). With α = 0 and
        `spin_accel_noise` = 0 this is the constant-rate model."""
        eye, zero = jnp.eye(3), jnp.zeros((3, 3))
        spin = jnp.block([[eye, dt * eye, 0.5 * dt**2 * eye], [zero, eye, dt * eye], [zero, zero, eye]])
        move = jnp.block([[eye, dt * eye], [zero, eye]])
        F = jax.scipy.linalg.block_diag(spin, move)
        q = jnp.concatenate(
            [
                jnp.zeros(3),
                jnp.full(3, rate_noise**2 * dt),
                jnp.full(3, spin_accel_noise**2 * dt),
                jnp.zeros(3),
                jnp.full(3, accel_noise**2 * dt),
            ]
        )
        return TrackFilter(
            _exp(self.rate * dt + 0.5 * self.spin_accel * dt**2) @ self.attitude,
            self.rate + dt * self.spin_accel,
            self.spin_accel,
            self.position + dt * self.velocity,
            self.velocity,
            F @ self.cov @ F.T + jnp.diag(q),
        )

    def update(self, rotation, point, noise: Float[Array, "6 6"]) -> TrackFilter:
        """Fuse a measured A (`rotation`) and tracked-point position (`point`, m) with
        covariance `noise` (rotation vector in rad, then metres)."""
        H = jnp.zeros((6, 15)).at[:3, :3].set(jnp.eye(3)).at[3:, 9:12].set(jnp.eye(3))
        residual = jnp.concatenate([_log(rotation @ self.attitude.T), point - self.position])
        S = H @ self.cov @ H.T + noise
        K = jnp.linalg.solve(S, H @ self.cov).T
        dx = K @ residual
        joseph = jnp.eye(15) - K @ H
        return TrackFilter(
            _exp(dx[:3]) @ self.attitude,
            self.rate + dx[3:6],
            self.spin_accel + dx[6:9],
            self.position + dx[9:12],
            self.velocity + dx[12:],
            joseph @ self.cov @ joseph.T + K @ noise @ K.T,
        )


class Chain(eqx.Module):
    """Per frame k (leading axis T): the chained motion since frame 0 (`rotations` R_0k,
    `translations` t_0k, camera frame c, m), the tracked point R_0k O_n + t_0k (`points`, m),
    the `status` of frame k's estimate (frame 0: success), and frame 0's plane origin O_n
    (`origin`, m, frame c). Frames whose estimate failed keep the last chained motion."""

    rotations: Float[Array, "T 3 3"]
    translations: Float[Array, "T 3"]
    points: Float[Array, "T 3"]
    status: Int[Array, " T"]
    origin: Float[Array, "3"]


class Track(eqx.Module):
    """Per frame k (leading axis T): the chained measurement (`rotations` R_0k, `points`),
    the `status` of its estimate, and the filtered `attitude`, `rate` (rad/s, frame c),
    `spin_accel` (rad/s², frame c), `position`, `velocity` and the filter's `rate_std`
    (rad/s, per axis)."""

    rotations: Float[Array, "T 3 3"]
    points: Float[Array, "T 3"]
    status: Int[Array, " T"]
    attitude: Float[Array, "T 3 3"]
    rate: Float[Array, "T 3"]
    spin_accel: Float[Array, "T 3"]
    position: Float[Array, "T 3"]
    velocity: Float[Array, "T 3"]
    rate_std: Float[Array, "T 3"]


def chain_estimates(clouds: Cloud, config: Config, key: PRNGKeyArray, keyframe_every: int = 25) -> Chain:
    """Register each frame against the current keyframe and chain the motions from frame 0.

    **Arguments:**

    - `clouds`: the frames (leading axis T; camera frame c, metres), e.g.
      `simulate_sequence(...).clouds`.
    - `config`: the estimate's [`jaxpose.Config`][] (its `max_points` must hold every frame).
    - `key`: frame k's estimate uses `fold_in(key, k)`.
    - `keyframe_every`: frames between keyframe switches (25 = 1 s at 25 Hz); a switch
      happens only on a successful frame.

    Pure and jittable (`lax.scan` over frames).
    """
    first = jax.tree.map(lambda x: x[0], clouds)
    origin = plane_frame(first).origin  # O_n of frame 0: the tracked point
    eye = jnp.eye(3, dtype=origin.dtype)

    def step(carry, inputs):
        key_cloud, key_R, key_t, last_R, last_t = carry
        k, cloud = inputs
        est = estimate_problem(Problem.build(key_cloud, cloud, config), config, jax.random.fold_in(key, k))
        ok = est.status == SUCCESS
        R = jnp.where(ok, est.rotation @ key_R, last_R)  # chain: frame 0 → keyframe → k
        t = jnp.where(ok, est.rotation @ key_t + est.translation, last_t)
        switch = (k % keyframe_every == 0) & ok
        key_cloud = jax.tree.map(lambda a, b: jnp.where(switch, a, b), cloud, key_cloud)
        key_R, key_t = jnp.where(switch, R, key_R), jnp.where(switch, t, key_t)
        return (key_cloud, key_R, key_t, R, t), (R, t, R @ origin + t, est.status)

    zeros = jnp.zeros(3, origin.dtype)
    frames = jnp.arange(1, clouds.valid.shape[0])
    rest = jax.tree.map(lambda x: x[1:], clouds)
    _, (R, t, points, status) = jax.lax.scan(step, (first, eye, zeros, eye, zeros), (frames, rest))
    head = (eye, zeros, origin, jnp.asarray(SUCCESS, status.dtype))
    R, t, points, status = (jnp.concatenate([h[None], o]) for h, o in zip(head, (R, t, points, status), strict=True))
    return Chain(R, t, points, status, origin)


def filter_chain(
    chain: Chain,
    dt: float,
    rotation_sigma: float = 0.005,
    point_sigma: float = 0.005,
    rate_noise: float = 1e-4,
    accel_noise: float = 1e-4,
    spin_accel_noise: float = 1e-4,
    spin_accel_sigma: float = 0.01,
) -> Track:
    """Run the EKF over a chain of measurements `dt` seconds apart.

    **Arguments:**

    - `chain`: from [`chain_estimates`][].
    - `rotation_sigma` (rad), `point_sigma` (m): measurement noise of a chained pose.
    - `rate_noise`, `spin_accel_noise`, `accel_noise`: the random-walk densities of
      [`TrackFilter.predict`][].
    - `spin_accel_sigma`: the initial standard deviation of α (rad/s²); 0 with
      `spin_accel_noise` = 0 is the constant-rate model.

    Frames whose estimate is not a success are skipped (prediction only). Pure and jittable.
    """
    noise = jnp.diag(jnp.concatenate([jnp.full(3, rotation_sigma**2), jnp.full(3, point_sigma**2)]))

    def step(filt, inputs):
        R, point, status = inputs
        filt = filt.predict(dt, rate_noise, accel_noise, spin_accel_noise)
        updated = filt.update(R, point, noise)
        filt = jax.tree.map(lambda a, b: jnp.where(status == SUCCESS, a, b), updated, filt)
        return filt, _row(filt)

    def _row(filt):
        std = jnp.sqrt(jnp.diag(filt.cov)[3:6])
        return filt.attitude, filt.rate, filt.spin_accel, filt.position, filt.velocity, std

    filt = TrackFilter.start(chain.origin, spin_accel_sigma=spin_accel_sigma)
    _, outs = jax.lax.scan(step, filt, (chain.rotations[1:], chain.points[1:], chain.status[1:]))
    filtered = (jnp.concatenate([h[None], o]) for h, o in zip(_row(filt), outs, strict=True))
    return Track(chain.rotations, chain.points, chain.status, *filtered)


def track(
    clouds: Cloud,
    dt: float,
    config: Config,
    key: PRNGKeyArray,
    keyframe_every: int = 25,
    **filter_options,
) -> Track:
    """Track a sequence of clouds (leading axis T, frames `dt` seconds apart):
    [`chain_estimates`][] then [`filter_chain`][] (`filter_options` go to the latter).
    Pure and jittable."""
    return filter_chain(chain_estimates(clouds, config, key, keyframe_every), dt, **filter_options)


__all__ = ["Chain", "Track", "TrackFilter", "chain_estimates", "filter_chain", "track"]
