"""Tracking: keyframe-chained `estimate` results and an extended Kalman filter (issue 7).

Two pure steps, also usable on their own: [`chain_estimates`][] registers every frame and
chains the motions, [`filter_keyframes`][] (or [`filter_chain`][]) runs a filter over them
(cheap, so a filter can be tuned on one set of registrations); [`track`][] is both.

**Chaining.** Frame k is registered against the current keyframe: the first frame, then the
first registered frame once the motion measured from the keyframe uses `keyframe_reach` of
the search box (or `keyframe_every` frames have passed). So the motion measured stays inside
the search box, and the errors of frame-to-frame steps do not add up at every frame: only
each keyframe switch adds its pair's error, and a slow tumble switches seldom. The motion
predicted at a constant rate (`predicted_motion`; after a refused frame carried on from an
anchor that averages the last registrations, `anchored_motion`) resolves an ambiguous registration and
accepts a weak one (low score, not converged, uncertain) where it agrees with it
(`continuity_choice`); with `guided` (the default), each registration also starts its second surface fit
from that prediction. The chained motion (R_0k, t_0k) maps frame 0's points to frame k's,
in the camera frame c.

**State** ([`TrackFilter`][], an `eqx.Module`): the target's rotation since frame 0,
A = R_0k (on SO(3), error state as a rotation vector on the left), its angular velocity ω
and angular acceleration α in frame c (rad/s, rad/s²), and the position and velocity (m,
m/s) of a tracked point (frame 0's plane origin O_n, moved with the target). Why α: a body
tumbling about a non-principal axis keeps its angular momentum, not its angular velocity;
for N5 at 4.5 °/s the apparent ω drifts by ≈ 0.06 °/s per second, which a constant-rate
model follows only with a lag (measured: 0.25 °/s error after 10 s). The shape, hence the
inertia, is unknown while the filter runs, so it cannot use Euler's equations; a
constant-acceleration model with a random walk on α follows a smooth drift without lag.
[`jaxpose.identify`][] fits Euler's equations to the whole track afterwards.

**Default filter** ([`KeyframeFilter`][], [`filter_keyframes`][]): the keyframe's pose is
cloned into the state (stochastic cloning) and each estimate keyframe → k is fused with its
own fine-stage covariance. Half of that covariance is carried by the clone, because every
registration against one keyframe shares that keyframe cloud's noise: a chained filter
reads the jump at each switch as motion. On the N5 tumbles of
`experiments/tumble_tracking.py` (4.5 °/s, 5.5 m, 1 cm noise, `Config.tracking()`) its rate
error after 10 s was 0.010–0.046 °/s over six noise seeds (docs, Tracking).

**Chained filter** ([`filter_chain`][]): the chained poses (R_0k, R_0k O_n + t_0k) as
measurements with a fixed noise; simpler, and 0.045–0.073 °/s on the same registrations.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from .._checks import is_concrete
from .._cloud import Cloud
from .._config import TRACKING_COVARIANCE_SCALE, Config, FineStage
from .._estimate import AMBIGUOUS, LOW_SCORE, NOT_CONVERGED, SUCCESS, UNCERTAIN, Hypotheses, estimate_problem
from .._frame import plane_frame
from .._poses import displacement_from_motion
from .._problem import Problem, sized_sequence_config
from .._programs import BoundedJit
from .._rotations import rotation_angle
from .._search import box_scale
from .._tree import tree_finite, tree_select
from .._uncertainty import motion_covariance, rotation_std

FILTER_UPDATED, FILTER_NO_ESTIMATE, FILTER_BAD_MEASUREMENT, FILTER_BAD_UPDATE = 0, 1, 2, 3
FILTER_STATUS_NAME = {
    FILTER_UPDATED: "updated",
    FILTER_NO_ESTIMATE: "no estimate",
    FILTER_BAD_MEASUREMENT: "bad measurement",
    FILTER_BAD_UPDATE: "bad update",
}
"""The filter's own per-frame status (`Track.filter_status`): the frame's measurement was fused
(frame 0, the filter's start, counts as updated); its estimate was no success; the measurement
or its covariance was unusable (see `measurement_usable`: non-finite, or the covariance not
symmetric positive semi-definite); or the update itself gave a non-finite state, a covariance
that is not positive semi-definite (`covariance_usable`) or an innovation covariance that is
not positive definite. In every case but the first the frame is a prediction only, so the
filter's state is never non-finite."""

SYMMETRY_TOL = 1e-6
"""Largest |Σ − Σᵀ| relative to max |Σ| for a measurement covariance to count as symmetric."""

PSD_TOL = 1e-5
"""Most negative eigenvalue of a usable measurement covariance, relative to its largest:
round-off of a float32 covariance of condition 10¹¹ (see `measurement_usable`)."""


def _positive_definite(S: Float[Array, "n n"]) -> Bool[Array, ""]:
    """Whether a finite symmetric matrix is positive definite: its Cholesky factor is finite
    (JAX returns NaN for one that is not)."""
    safe = jnp.where(jnp.all(jnp.isfinite(S)), S, jnp.eye(S.shape[0], dtype=S.dtype))
    return jnp.all(jnp.isfinite(S)) & jnp.all(jnp.isfinite(jnp.linalg.cholesky(safe)))


def measurement_usable(rotation, translation, cov: Float[Array, "6 6"]) -> Bool[Array, ""]:
    """Whether a measured motion can be fused: rotation (3, 3) and translation (3,, m) finite,
    and its covariance `cov` (rad, then m) finite, symmetric (`SYMMETRY_TOL`), not zero and
    positive semi-definite to within `PSD_TOL` of its largest eigenvalue. Jittable; the
    filters skip a frame that fails it and flag it `FILTER_BAD_MEASUREMENT`.

    Semi-definite, not definite: where the visible faces leave a direction free (a slide
    along N5's faces), the point-to-plane covariance is huge along it and tiny across
    (condition ≈ 10¹¹), which no float32 Cholesky factor resolves; the measurement still
    carries its information, and the update's own check (a positive definite innovation
    covariance) guards the numerics."""
    return tree_finite((rotation, translation)) & covariance_usable(cov)


def covariance_usable(cov: Float[Array, "n n"]) -> Bool[Array, ""]:
    """Whether a covariance is finite, symmetric (`SYMMETRY_TOL`), not zero and positive
    semi-definite to within `PSD_TOL` of its largest eigenvalue (see `measurement_usable`)."""
    finite = jnp.all(jnp.isfinite(cov))
    safe = jnp.where(finite, cov, jnp.eye(cov.shape[0], dtype=cov.dtype))
    return _usable(finite, safe, jnp.linalg.eigvalsh((safe + safe.T) / 2))


def _usable(finite, safe, eig) -> Bool[Array, ""]:
    """`covariance_usable` from its parts: whether the covariance was `finite`, its finite
    stand-in `safe`, and the eigenvalues `eig` (ascending) of safe's symmetric part."""
    symmetric = jnp.max(jnp.abs(safe - safe.T)) <= SYMMETRY_TOL * jnp.max(jnp.abs(safe))
    semidefinite = (eig[-1] > 0) & (eig[0] >= -PSD_TOL * eig[-1])
    return finite & symmetric & semidefinite


def nearest_semidefinite(cov: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """`cov` with round-off's indefiniteness removed: itself where it is a usable covariance
    (`covariance_usable`, returned bit for bit) or where its most negative eigenvalue exceeds
    `REPAIRABLE` of the largest (not round-off: left for the callers' checks to refuse);
    otherwise the symmetric matrix with its eigenvectors and its eigenvalues raised to at
    least `SEMIDEFINITE_FLOOR` of the largest.

    Why: float32 round-off in the filter's products (F P Fᵀ, the Joseph form, the keyframe
    clone) scales with the largest variance; after many near-exact measurements (a noise-free
    view) the attitude's and rate's variances fall below it and can turn negative. A filter
    that refused every such update kept predicting from a covariance that was itself no
    longer semi-definite, and `rate_std` became NaN for every later frame (a noise-free N5
    tumble of the tracking benchmark's second draw)."""
    finite = jnp.all(jnp.isfinite(cov))
    safe = jnp.where(finite, cov, jnp.eye(cov.shape[0], dtype=cov.dtype))
    eig, vec = jnp.linalg.eigh((safe + safe.T) / 2)
    largest = jnp.maximum(eig[-1], jnp.finfo(cov.dtype).tiny)
    lifted = (vec * jnp.maximum(eig, SEMIDEFINITE_FLOOR * largest)[None, :]) @ vec.T
    repair = finite & ~_usable(finite, safe, eig) & (eig[0] >= -REPAIRABLE * largest)
    return jnp.where(repair, (lifted + lifted.T) / 2, cov)


SEMIDEFINITE_FLOOR = 1e-6
"""Smallest eigenvalue, relative to the largest, of a covariance that `nearest_semidefinite`
repairs: about ten times float32's round-off, so that the repaired matrix stays
semi-definite after its own round-off."""

REPAIRABLE = 1e-3
"""Most negative eigenvalue, relative to the largest, that `nearest_semidefinite` takes for
round-off and repairs; a covariance further from semi-definite is a fault, not round-off."""


def _guarded_update(filt, predicted, updated, estimate_ok, usable, innovation_ok):
    """The updated filter where every check passed, else the prediction; and the frame's
    filter status (see `FILTER_STATUS_NAME`). An updated covariance that round-off left
    slightly indefinite is repaired (`semidefinite`) before the checks; one that is still not
    positive semi-definite, or not finite, refuses the update, so that no later standard
    deviation is the root of a negative variance."""
    updated = updated.semidefinite()
    good_update = innovation_ok & tree_finite(updated) & covariance_usable(updated.cov)
    status = jnp.select(
        [~estimate_ok, ~usable, ~good_update],
        [FILTER_NO_ESTIMATE, FILTER_BAD_MEASUREMENT, FILTER_BAD_UPDATE],
        FILTER_UPDATED,
    )
    return tree_select(status == FILTER_UPDATED, updated, predicted), status.astype(jnp.int32)


def _exp(v):
    return jaxlie.SO3.exp(v).as_matrix()


def _log(R):
    return jaxlie.SO3.from_matrix(R).log()


def _transition(dt, rate_noise, accel_noise, spin_accel_noise):
    """Error-state transition F (15, 15) and process noise Q (15, 15) over `dt` seconds."""
    eye, zero = jnp.eye(3), jnp.zeros((3, 3))
    spin = jnp.block([[eye, dt * eye, 0.5 * dt**2 * eye], [zero, eye, dt * eye], [zero, zero, eye]])
    move = jnp.block([[eye, dt * eye], [zero, eye]])
    densities = (0.0, rate_noise, spin_accel_noise, 0.0, accel_noise)
    q = jnp.concatenate([jnp.full(3, n**2 * dt) for n in densities])
    return jax.scipy.linalg.block_diag(spin, move), jnp.diag(q)


ERR_ATTITUDE, ERR_RATE, ERR_SPIN_ACCEL, ERR_POSITION, ERR_VELOCITY = (slice(3 * i, 3 * i + 3) for i in range(5))
"""Blocks of the (15,) error state (δφ, δω, δα, δr, δv) of `TrackFilter`."""
ERR_STATE, ERR_KEY_ATTITUDE, ERR_KEY_POSITION = slice(0, 15), slice(15, 18), slice(18, 21)
"""Blocks of `KeyframeFilter`'s (21,) error state: the current state, then the keyframe's
clone of δφ and δr."""


def _innovation(cov, H, noise):
    """Innovation covariance S = H P Hᵀ + R of a measurement with Jacobian H and noise R."""
    return H @ cov @ H.T + noise


def _kalman_step(cov, H, residual, noise):
    """The error-state correction dx and the updated covariance (Joseph form) of one update."""
    S = _innovation(cov, H, noise)
    K = jnp.linalg.solve(S, H @ cov).T
    joseph = jnp.eye(cov.shape[0], dtype=cov.dtype) - K @ H
    updated = joseph @ cov @ joseph.T + K @ noise @ K.T
    return K @ residual, (updated + updated.T) / 2


def _skew(v):
    return jnp.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


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

    def predict(
        self,
        dt: Float[ArrayLike, ""],
        rate_noise: Float[ArrayLike, ""],
        accel_noise: Float[ArrayLike, ""],
        spin_accel_noise: Float[ArrayLike, ""] = 0.0,
    ) -> TrackFilter:
        """Propagate by `dt` seconds. Random-walk densities: `rate_noise` on ω (rad/s/√s),
        `spin_accel_noise` on α (rad/s²/√s), `accel_noise` on v (m/s/√s). With α = 0 and
        `spin_accel_noise` = 0 this is the constant-rate model."""
        F, q = _transition(dt, rate_noise, accel_noise, spin_accel_noise)
        return TrackFilter(
            _exp(self.rate * dt + 0.5 * self.spin_accel * dt**2) @ self.attitude,
            self.rate + dt * self.spin_accel,
            self.spin_accel,
            self.position + dt * self.velocity,
            self.velocity,
            F @ self.cov @ F.T + q,
        )

    def update(self, rotation, point, noise: Float[Array, "6 6"]) -> TrackFilter:
        """Fuse a measured A (`rotation`) and tracked-point position (`point`, m) with
        covariance `noise` (rotation vector in rad, then metres)."""
        residual = jnp.concatenate([_log(rotation @ self.attitude.T), point - self.position])
        dx, cov = _kalman_step(self.cov, _POSE_ROWS, residual, noise)
        return self.corrected(dx, cov)

    def corrected(self, dx: Float[Array, "15"], cov: Float[Array, "15 15"]) -> TrackFilter:
        """The state moved by the error-state correction `dx`, with covariance `cov`."""
        return TrackFilter(
            _exp(dx[ERR_ATTITUDE]) @ self.attitude,
            self.rate + dx[ERR_RATE],
            self.spin_accel + dx[ERR_SPIN_ACCEL],
            self.position + dx[ERR_POSITION],
            self.velocity + dx[ERR_VELOCITY],
            cov,
        )

    def innovation_ok(self, noise: Float[Array, "6 6"]) -> Bool[Array, ""]:
        """Whether the innovation covariance of an [`update`][] with `noise` is positive definite."""
        S = _innovation(self.cov, _POSE_ROWS, noise)
        return _positive_definite((S + S.T) / 2)

    def semidefinite(self) -> TrackFilter:
        """This state with its covariance repaired where round-off left it indefinite
        (`nearest_semidefinite`)."""
        return eqx.tree_at(lambda f: f.cov, self, nearest_semidefinite(self.cov))


_POSE_ROWS = np.zeros((6, 15), np.float32)
_POSE_ROWS[:3, ERR_ATTITUDE] = _POSE_ROWS[3:, ERR_POSITION] = np.eye(3)
"""Measurement matrix of a pose (attitude error, then tracked-point position) on the
(15,) error state of `TrackFilter`."""


class Chain(eqx.Module):
    """Per frame k (leading axis T): the chained motion since frame 0 (`rotations` R_0k,
    `translations` t_0k, camera frame c, m), the tracked point R_0k O_n + t_0k (`points`, m),
    the `status` of frame k's estimate (frame 0: success), and frame 0's plane origin O_n
    (`origin`, m, frame c). Frames whose estimate failed keep the last chained motion.

    The measurement itself, keyframe → k, is kept too: `relative_rotations` and
    `relative_translations` (camera frame c), their covariance `relative_cov` (6, 6; the
    rotation as a left rotation vector in rad, then the translation in m; from the fine
    stage's least squares scaled by `TRACKING_COVARIANCE_SCALE`, identity·1e-4 where the fine
    stage is off) and `switched` (frame k became the keyframe after its estimate).

    `continuity` (None: none): motion continuity made frame k's estimate a registration
    (`continuity_choice`): an `ambiguous` estimate, whose measurement is the hypothesis
    nearest the prediction, or a weak one (low score, not converged, uncertain) that agrees with the
    prediction; such a frame counts as registered."""

    rotations: Float[Array, "T 3 3"]
    translations: Float[Array, "T 3"]
    points: Float[Array, "T 3"]
    status: Int[Array, " T"]
    origin: Float[Array, "3"]
    relative_rotations: Float[Array, "T 3 3"]
    relative_translations: Float[Array, "T 3"]
    relative_cov: Float[Array, "T 6 6"]
    switched: Bool[Array, " T"]
    continuity: Bool[Array, " T"] | None = None


measurement_covariance = motion_covariance
"""The covariance of a registration's measurement ([`motion_covariance`][jaxpose._uncertainty.motion_covariance])."""


def chained_motions(
    rotations: Float[Array, "T 3 3"], points: Float[Array, "T 3"]
) -> tuple[Float[Array, "T 3"], Bool[Array, " T"]]:
    """The motion from the first frame to frame k, x ↦ R_0k x + t_k in frame c (metres), from
    the chained rotations and tracked points: t_k = r_k − R_0k r_0, so that the tracked point
    r_0 goes to r_k. Returns the translations (T, 3) and whether frame k's motion is finite."""
    translations = points - jnp.einsum("tij,j->ti", rotations, points[0])
    finite = jnp.all(jnp.isfinite(rotations), axis=(1, 2)) & jnp.all(jnp.isfinite(translations), axis=1)
    return translations, finite


class Track(eqx.Module):
    """Per frame k (leading axis T): the chained measurement (`rotations` R_0k, `points`),
    the `status` of its estimate, and the filtered `attitude`, `rate` (rad/s, frame c),
    `spin_accel` (rad/s², frame c), `position`, `velocity`, the filter's `rate_std`
    (rad/s, per axis) and its own per-frame `filter_status` (`FILTER_STATUS_NAME`: whether the
    frame's measurement was fused, or why not). Every filtered output is finite.

    The registrations themselves: frame k was registered against frame `keyframes[k]` (frame
    0 against itself), so the measurement keyframe → k is R_0k R_0jᵀ for j = `keyframes[k]`,
    with the covariance `measurement_cov[k]` (6, 6; a left rotation vector in rad, then the
    translation in m; from the fine stage, as `Chain.relative_cov`). Frames registered
    against one keyframe share its noise; chaining adds each keyframe's error to all later
    frames. [`jaxpose.identify`][] uses these. `continuity` (as `Chain.continuity`): frames
    whose ambiguous or weak estimate motion continuity resolved; they count as registered
    (`registered`)."""

    @classmethod
    def of_measurements(
        cls,
        rotations: Float[Array, "T 3 3"],
        points: Float[Array, "T 3"],
        keyframes: Int[Array, " T"],
        measurement_cov: Float[Array, "T 6 6"],
        status: Int[Array, " T"] | None = None,
    ) -> Track:
        """A track of measurements alone, made elsewhere (a saved run, another tracker, exact
        motions): what [`jaxpose.identify`][] and [`jaxpose.track_against_model`][] read.
        No filter ran, so `filter_status` is `FILTER_NO_ESTIMATE` on every frame, the filtered
        attitude and position are the measurements themselves and the rates are zero.
        `status` defaults to success on every frame. Frames, units: as the fields."""
        T = rotations.shape[0]
        zeros = jnp.zeros((T, 3), rotations.dtype)
        status = jnp.full(T, SUCCESS, jnp.int32) if status is None else jnp.asarray(status, jnp.int32)
        return cls(
            rotations=rotations,
            points=points,
            status=status,
            attitude=rotations,
            rate=zeros,
            spin_accel=zeros,
            position=points,
            velocity=zeros,
            rate_std=zeros,
            filter_status=jnp.full(T, FILTER_NO_ESTIMATE, jnp.int32),
            keyframes=jnp.asarray(keyframes, jnp.int32),
            measurement_cov=measurement_cov,
        )

    def motions(self) -> tuple[Float[Array, "T 3"], Bool[Array, " T"]]:
        """The translations t_k of the motions x ↦ `rotations`[k] x + t_k from the first frame
        to frame k (frame c, metres), t_k = `points`[k] − `rotations`[k] `points`[0], and
        whether each is finite."""
        return chained_motions(self.rotations, self.points)

    def registered(self) -> Bool[Array, " T"]:
        """Frames whose measurement entered the chain: a successful estimate, or an ambiguous
        or weak one resolved by continuity."""
        return is_registered(self.status, self.continuity)

    rotations: Float[Array, "T 3 3"]
    points: Float[Array, "T 3"]
    status: Int[Array, " T"]
    attitude: Float[Array, "T 3 3"]
    rate: Float[Array, "T 3"]
    spin_accel: Float[Array, "T 3"]
    position: Float[Array, "T 3"]
    velocity: Float[Array, "T 3"]
    rate_std: Float[Array, "T 3"]
    filter_status: Int[Array, " T"]
    keyframes: Int[Array, " T"]
    measurement_cov: Float[Array, "T 6 6"]
    continuity: Bool[Array, " T"] | None = None


class KeyframeFilter(eqx.Module):
    """EKF with a cloned keyframe (stochastic cloning): the [`TrackFilter`][] state (`now`)
    plus the attitude A_key and tracked-point position r_key at the current keyframe, with
    one covariance `cov` (21, 21) over (δφ, δω, δα, δr, δv, δφ_key, δr_key); `now.cov` is
    its leading (15, 15) block.

    Why: a chained measurement carries every earlier keyframe switch's error, so successive
    measurements share errors the plain filter takes as independent. Here each measurement
    is the estimate itself, keyframe → k: A_k = R_rel A_key and r_k = R_rel r_key + t_rel,
    with the estimate's own covariance; the keyframe's uncertainty lives in the state."""

    now: TrackFilter
    key_attitude: Float[Array, "3 3"]
    key_position: Float[Array, "3"]
    cov: Float[Array, "21 21"]

    @classmethod
    def start(cls, position, **start_options) -> KeyframeFilter:
        """At frame 0, which is the first keyframe (see [`TrackFilter.start`][])."""
        now = TrackFilter.start(position, **start_options)
        return cls(now, now.attitude, now.position, _clone_cov(now.cov))

    def predict(
        self,
        dt: Float[ArrayLike, ""],
        rate_noise: Float[ArrayLike, ""],
        accel_noise: Float[ArrayLike, ""],
        spin_accel_noise: Float[ArrayLike, ""],
    ) -> KeyframeFilter:
        """Propagate the current state; the keyframe clone does not move."""
        F, q = _transition(dt, rate_noise, accel_noise, spin_accel_noise)
        F = jax.scipy.linalg.block_diag(F, jnp.eye(6))
        Q = jax.scipy.linalg.block_diag(q, jnp.zeros((6, 6)))
        cov = F @ self.cov @ F.T + Q
        now = eqx.tree_at(
            lambda f: f.cov, self.now.predict(dt, rate_noise, accel_noise, spin_accel_noise), cov[ERR_STATE, ERR_STATE]
        )
        return KeyframeFilter(now, self.key_attitude, self.key_position, cov)

    def update(self, R_rel, t_rel, noise: Float[Array, "6 6"]) -> KeyframeFilter:
        """Fuse a measured keyframe → now motion (R_rel, t_rel; camera frame c) with
        covariance `noise` (left rotation vector in rad, then m)."""
        dx, cov = _kalman_step(self.cov, self._jacobian(), self._residual(R_rel, t_rel), noise)
        now = self.now.corrected(dx[ERR_STATE], cov[ERR_STATE, ERR_STATE])
        key_attitude = _exp(dx[ERR_KEY_ATTITUDE]) @ self.key_attitude
        return KeyframeFilter(now, key_attitude, self.key_position + dx[ERR_KEY_POSITION], cov)

    def _residual(self, R_rel, t_rel) -> Float[Array, "6"]:
        """The measured keyframe → now motion less the predicted one (left rotation vector in
        rad, then m)."""
        M, Mr = self._predicted_motion()
        return jnp.concatenate([_log(R_rel @ M.T), t_rel - (self.now.position - Mr)])

    def _predicted_motion(self):
        """The predicted keyframe → now rotation M = A_now A_keyᵀ and M r_key (m)."""
        M = self.now.attitude @ self.key_attitude.T
        return M, M @ self.key_position

    def _jacobian(self) -> Float[Array, "6 21"]:
        """Jacobian of the predicted keyframe → now motion (left rotation vector, then
        translation) with respect to the (21,) error state."""
        M, Mr = self._predicted_motion()
        rot, move = slice(0, 3), slice(3, 6)
        H = jnp.zeros((6, 21), self.cov.dtype)
        H = H.at[rot, ERR_ATTITUDE].set(jnp.eye(3)).at[rot, ERR_KEY_ATTITUDE].set(-M)
        H = H.at[move, ERR_ATTITUDE].set(_skew(Mr)).at[move, ERR_KEY_ATTITUDE].set(-_skew(Mr) @ M)
        # Residual t: t_rel − (r − M r_key); δ(r − M r_key) = δr − M δr_key + [M r_key]× δθ.
        return H.at[move, ERR_POSITION].set(jnp.eye(3)).at[move, ERR_KEY_POSITION].set(-M)

    def innovation_ok(self, noise: Float[Array, "6 6"]) -> Bool[Array, ""]:
        """Whether the innovation covariance of an [`update`][] with `noise` is positive definite."""
        S = _innovation(self.cov, self._jacobian(), noise)
        return _positive_definite((S + S.T) / 2)

    def semidefinite(self) -> KeyframeFilter:
        """This state with its (21, 21) covariance repaired where round-off left it indefinite
        (`nearest_semidefinite`); `now.cov` stays its leading block."""
        cov = nearest_semidefinite(self.cov)
        now = eqx.tree_at(lambda f: f.cov, self.now, cov[ERR_STATE, ERR_STATE])
        return KeyframeFilter(now, self.key_attitude, self.key_position, cov)

    def clone(self, shared: Float[Array, "6 6"] | None = None) -> KeyframeFilter:
        """Make the current state the keyframe (after frame k becomes the new keyframe).

        `shared`: covariance (left rotation vector in rad, then m) of the part of the coming
        registrations' error that they all share, because they are all registered against
        this keyframe's one noisy cloud; it is carried by the clone, so the filter treats it
        as one offset of the whole segment rather than as independent noise."""
        cov = _clone_cov(self.cov[ERR_STATE, ERR_STATE])
        if shared is not None:
            # A registration error e = (e_φ, e_t) common to the segment is a clone error
            # δφ_key = −e_φ, δr_key = [r_key]× e_φ − e_t (at the clone, where R_rel = I; see
            # the Jacobian in `update`).
            T = jnp.block([[-jnp.eye(3), jnp.zeros((3, 3))], [_skew(self.now.position), -jnp.eye(3)]])
            clone = slice(ERR_KEY_ATTITUDE.start, ERR_KEY_POSITION.stop)
            cov = cov.at[clone, clone].add(T @ shared @ T.T)
        return KeyframeFilter(self.now, self.now.attitude, self.now.position, cov)


def _clone_cov(P15):
    """Covariance (21, 21) of (state, copy of its δφ and δr) from the state's (15, 15)."""
    pick = jnp.asarray(_POSE_ROWS, P15.dtype)  # δφ and δr
    T = jnp.concatenate([jnp.eye(15), pick])
    return T @ P15 @ T.T


CONTINUITY_FRACTION = 0.5
"""An ambiguous estimate is resolved by continuity when one of its distinct hypotheses lies
within this fraction of `Thresholds.ambiguous_deg` of the predicted rotation (the fits of an
ambiguous estimate are more than `ambiguous_deg` apart, so at most one can)."""


KEYFRAME_EVERY = 250
"""Default of `keyframe_every`: the most frames between keyframe switches (10 s at 25 Hz; the
motion, `KEYFRAME_REACH`, usually decides first)."""

KEYFRAME_REACH: float | None = 0.4
"""Default of `keyframe_reach`: the share of the search box that the motion from the keyframe
may use before a switch is due (see `motion_reached`): 8° about a plane axis or 4 cm of the
plane origin's shift with the default box. Each switch adds that frame's registration error
to every later frame, so a slow tumble should switch seldom; registrations against one
keyframe kept their accuracy up to 10–12° of rotation and lost it beyond 15°
(`experiments/tracking_benchmark.py reach`, docs, Tracking)."""


def is_registered(status: Int[Array, " T"], continuity: Bool[Array, " T"] | None) -> Bool[Array, " T"]:
    """A successful estimate, or an ambiguous or weak one that motion continuity resolved."""
    ok = status == SUCCESS
    return ok if continuity is None else ok | continuity


WEAK_FRACTION = 1.0
"""A weak estimate (`Status.low_score`, `Status.not_converged` or `Status.uncertain`) is accepted by continuity when
it lies within this fraction of `Thresholds.ambiguous_deg` of the predicted rotation, or
within the extrapolation gate (`WEAK_SIGMAS`), whichever is wider. Under range noise the
pattern score falls below `Thresholds.min_score` for estimates as good as the successes;
refusing them all had left such tumbles without a single keyframe switch, so the motion from
the keyframe grew until nothing registered (docs, Tracking)."""

CLEAR_RATIO = 3.0
"""An ambiguous estimate whose nearest distinct hypothesis lies beyond the fixed gate
(`CONTINUITY_FRACTION`) is still resolved by it when it lies within the extrapolation gate
(`WEAK_SIGMAS`, `WEAK_MAX_DEG`) and every other distinct hypothesis lies at least this many
times as far from the prediction: the choice is then clear although the prediction has
drifted. With the fixed gate alone, a slow tumble of the near-axisymmetric upper stage
(the tracking benchmark's tumble 48, σ = 0.5 cm, 3.1 °/s), whose every estimate was
ambiguous about its long axis after the first frames, registered 8 of 251 frames: the
prediction, extrapolated from the first 0.6 s, drifted beyond 0.5° of the truth and never
came back (docs, Tracking)."""

WEAK_SIGMAS = 3.0
"""The extrapolation gate of a weak estimate: this many standard deviations of the
prediction's extrapolation error (`prediction_spread`), at most `WEAK_MAX_DEG`. A prediction
extrapolated from a short baseline carries its registrations' error times the frames ahead
over the baseline: with the fixed 1° gate alone, a track whose registrations are all weak
could accept one frame and refuse every later one (the fragment at 2 cm of range noise,
tumble 19 of the tracking benchmark: 2 of 251 frames registered; docs, Tracking)."""

WEAK_MAX_DEG = 3.0
"""The widest extrapolation gate, degrees (`WEAK_SIGMAS`): a registration that lands in a
wrong minimum is usually several degrees off (a turn about a near-symmetry axis, a face laid
onto another), and a gate this wide still refuses most of them."""


def prediction_spread(
    sigma: Float[ArrayLike, ""], k: Int[ArrayLike, ""], last_k: Int[ArrayLike, ""], base_k: Int[ArrayLike, ""]
) -> Float[Array, ""]:
    """The standard deviation (the unit of `sigma`) of the extrapolation error of the rotation
    predicted for frame k at a constant rate from frames `base_k` and `last_k`
    (`predicted_motion`), when each registration's rotation has the standard deviation
    `sigma`. The prediction is last + a (last − base), a = (k − last_k) / (last_k − base_k),
    so its error has the variance σ² ((1 + a)² + a²): σ² of the last registration, which the
    fixed gate covers (`WEAK_FRACTION`), and σ² 2a (1 + a) from the extrapolation, whose
    square root this returns. It vanishes for a long baseline (a → 0) and grows with the
    frames ahead over the baseline. With nothing registered since frame 0 (`last_k` =
    `base_k`) the prediction is rest, and it is 0.

    Counting the whole σ √(1 + (1 + a)² + a²) instead widened the gate on long baselines too,
    and in a trial on the tracking benchmark a noise-free fragment then accepted weak
    registrations 2–3° off, which led the prediction astray until nothing registered (docs,
    Tracking)."""
    sigma = jnp.asarray(sigma)
    span = jnp.asarray(last_k - base_k)
    a = jnp.where(span > 0, (k - last_k) / jnp.maximum(span, 1), 0.0).astype(sigma.dtype)
    return sigma * jnp.sqrt(2 * a * (1 + a))


def continuity_choice(
    hypotheses: Hypotheses,
    status: Int[Array, ""],
    R_pred: Float[Array, "3 3"],
    config: Config,
    spread: Float[ArrayLike, ""] = 0.0,
):
    """What motion continuity makes of an estimate (its `hypotheses` and `status`) given the
    predicted rotation `R_pred` (keyframe → now, camera frame). Returns (index, resolved):

    - ambiguous: the distinct hypothesis nearest the prediction, resolved when it lies within
      `CONTINUITY_FRACTION` × `Thresholds.ambiguous_deg` of it, or within the extrapolation
      gate below with every other distinct hypothesis `CLEAR_RATIO` times as far;
    - weak (low score, not converged or uncertain): the estimate itself (index 0), accepted
      when it lies within `WEAK_FRACTION` × `Thresholds.ambiguous_deg` of the prediction, or
      within `WEAK_SIGMAS` × `spread` (radians: the standard deviation of the prediction's
      extrapolation error, `prediction_spread`), at most `WEAK_MAX_DEG`;
    - otherwise: index 0, not resolved (a success needs no continuity, a degenerate,
      non-finite or boxed-in estimate gets none)."""
    H = hypotheses
    angle = jnp.where(H.distinct, rotation_angle(H.rotation, jnp.broadcast_to(R_pred, H.rotation.shape)), jnp.inf)
    nearest = jnp.argmin(angle)
    gate = jnp.radians(config.thresholds.ambiguous_deg)
    extrapolation_gate = jnp.minimum(WEAK_SIGMAS * jnp.nan_to_num(jnp.asarray(spread)), jnp.radians(WEAK_MAX_DEG))
    runner_up = jnp.min(jnp.where(jnp.arange(angle.shape[0]) == nearest, jnp.inf, angle))
    clear = angle[nearest] <= CONTINUITY_FRACTION * gate
    extrapolated = (angle[nearest] <= extrapolation_gate) & (runner_up >= CLEAR_RATIO * angle[nearest])
    ambiguous = (status == AMBIGUOUS) & (clear | extrapolated)
    weak = ((status == LOW_SCORE) | (status == NOT_CONVERGED) | (status == UNCERTAIN)) & (
        angle[0] <= jnp.maximum(WEAK_FRACTION * gate, extrapolation_gate)
    )
    return jnp.where(ambiguous, nearest, 0), ambiguous | weak


def _se3(R: Float[ArrayLike, "3 3"], t: Float[ArrayLike, "3"]) -> jaxlie.SE3:
    """The motion x ↦ R x + t as a jaxlie SE(3) element."""
    return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(R), t)


def predicted_motion(before, last, keyframe, k):
    """The motion from the keyframe to frame k (camera frame, x ↦ R x + t) predicted at a
    constant rate: the screw motion from `before` to `last` (each (R, t, index) of the motion
    from frame 0; `chain_estimates` passes the keyframe before the current one and the last
    registered frame, or the anchor there after a refused frame (`anchored_motion`), a whole
    keyframe segment apart once a switch has happened, so that one registration's error is
    divided by a long baseline), carried on from `last` to frame k (SE(3) log and exp,
    jaxlie). `keyframe` is (R, t) of the keyframe from frame 0. With `before` and `last` the
    same frame the prediction is no motion."""
    (R0, t0, k0), (R1, t1, k1), (Rk, tk) = before, last, keyframe
    step = (_se3(R1, t1) @ _se3(R0, t0).inverse()).log() / jnp.maximum(k1 - k0, 1).astype(t1.dtype)
    ahead = jaxlie.SE3.exp(step * (k - k1).astype(t1.dtype)) @ _se3(R1, t1)
    relative = ahead @ _se3(Rk, tk).inverse()
    return relative.rotation().as_matrix(), relative.translation()


ANCHOR_WEIGHT = 0.25
"""How far each registered frame moves the prediction's anchor (`anchored_motion`) from
the motion predicted for it towards the motion registered. The anchor carries the
prediction after a refused frame (`chain_estimates`); otherwise the last registration does,
and its whole error then carries into the next frame's gate. With a weight w and
registrations of independent errors σ, the anchor's error has the standard deviation
σ √(w / (2 − w)), 0.38 σ at 0.25, and it lags a change of the rate by (1 − w) / w = 3 frames.
On the tracking benchmark's fragment at 1 cm of range noise (tumble 54, a third draw), the
last registration before frame 40 was 1.3° off, the good estimates that followed (0.1–0.9°
off) lay 1–2.9° from a prediction anchored on it, and every one of the remaining 211 frames
was refused; from the anchor after a refusal, 228 of its 251 frames registered. Anchoring
every prediction instead (a scratch run of the three draws) raised the benchmark's median
rate error from 0.065 to 0.082 °/s (docs, Tracking)."""


def anchor_weight(
    count: Int[ArrayLike, ""], k: Int[ArrayLike, ""], last_k: Int[ArrayLike, ""], base_k: Int[ArrayLike, ""]
) -> Float[Array, ""]:
    """The weight of frame k's registration in the prediction's anchor (`anchored_motion`):
    `ANCHOR_WEIGHT`, but no less than a running mean's 1 / `count` over the first `count`
    registrations (so that the first predictions, extrapolated from the first registrations,
    are not drawn towards rest), and no less than the share of the prediction's
    extrapolation variance in the sum of it and the registration's: 2a(1 + a) / (1 + 2a(1 + a)),
    a = (k − last_k) / (last_k − base_k) (`prediction_spread`), so that after missed frames, or
    on a short baseline, a prediction that has drifted does not hold the anchor back. Two
    frames of a constant motion in a row (a → 0) give `ANCHOR_WEIGHT`; a frame as far ahead of
    the last registration as that is from the base (a = 1), 0.8."""
    extrapolation = prediction_spread(1.0, k, last_k, base_k) ** 2
    share = extrapolation / (1.0 + extrapolation)
    running_mean = 1.0 / jnp.maximum(jnp.asarray(count), 1)
    return jnp.maximum(jnp.maximum(ANCHOR_WEIGHT, running_mean), share)


def anchored_motion(predicted, registered, weight: Float[ArrayLike, ""] = ANCHOR_WEIGHT):
    """The prediction's anchor at a registered frame: the motion from frame 0 (R, t, camera
    frame c) moved from the `predicted` one by `weight` of the way to the `registered` one,
    along the SE(3) geodesic (jaxlie). `weight` 1 is the registration itself."""
    start = _se3(*predicted)
    step = (_se3(*registered) @ start.inverse()).log() * jnp.asarray(weight, predicted[1].dtype)
    moved = jaxlie.SE3.exp(step) @ start
    return moved.rotation().as_matrix(), moved.translation()


def keyframe_switch(
    k: Int[Array, ""],
    key_k: Int[Array, ""],
    keyframe_every: int,
    registered: Bool[Array, ""],
    reached: Bool[Array, ""] | bool = False,
):
    """Whether frame k becomes the keyframe: the switch is due `keyframe_every` frames after
    the last keyframe `key_k`, or as soon as the motion measured from the keyframe has
    `reached` its limit (`motion_reached`), and happens at the first `registered` frame from
    then on. Waiting for the next multiple of `keyframe_every` instead would let the motion from
    the keyframe grow by another `keyframe_every` frames after one missed frame, and a larger
    motion is more often missed again (a noise-free fragment at 8 °/s lost its track that way)."""
    return ((k - key_k >= keyframe_every) | reached) & registered


def motion_reached(p: Float[Array, "6"], config: Config, keyframe_reach: float | None) -> Bool[Array, ""]:
    """Whether a motion from the keyframe, p (frame n of the keyframe, radians and metres),
    uses `keyframe_reach` of the search box in any component (`GlobalSearch.angle_box`,
    `shift_box`): the next frames would soon leave the box. False where `keyframe_reach` is
    None or the config searches the whole rotation group instead of a box (`Config.capture()`)."""
    if keyframe_reach is None or config.so3 is not None:
        return jnp.asarray(False)
    return jnp.any(jnp.abs(p) >= keyframe_reach * box_scale(config).astype(p.dtype))


def registration_config(config: Config) -> Config:
    """The config of the tracker's registrations: `config` with `Thresholds.min_rotation_lever`
    and `Thresholds.min_translation_grip` = 0. A pair whose matched faces barely hold a turn
    (`Estimate.hold`) or a translation (`Estimate.slide`) is `Status.uncertain` on its own, and
    the tracker accepts an uncertain registration only where it agrees with the prediction:
    continuity, not the single pair, judges it. The translation check has not been run on the
    tracking benchmark; the tracker keeps the registrations that benchmark measured. On the
    tracking benchmark's noise-free grazing fragment (tumble 4: a bent panel, nearly one face)
    its registrations often have such a turn; with the lever check, 12 of its 251 frames
    registered and the track was lost (rate error 13.8 °/s at 10 s), without it 198
    (0.24 °/s), the other 19 tumbles the same either way (docs, Tracking). Those
    registrations still go to the filter with their least-squares covariance, which does not
    widen along the free turn. That covariance is scaled by `TRACKING_COVARIANCE_SCALE`
    (`FineStage.covariance_scale`), the scale the filter and its gates were tuned with, rather than
    the estimate's default realistic calibration."""
    config = eqx.tree_at(
        lambda c: (c.thresholds.min_rotation_lever, c.thresholds.min_translation_grip), config, (0.0, 0.0)
    )
    return tracking_scale(config)


def default_tracking_config() -> Config:
    """The tracker's config when none is given: `Config()` with one-way fine-stage residuals
    (`FineStage.symmetric` False), the registrations the tracking benchmark measured. With
    two-way residuals the benchmark lost its noise-free grazing fragment and the rate error
    grew on 6 of the 10 other tumbles it reached (docs, Findings: two-way residuals); pass a
    config to choose otherwise."""
    return Config(fine=FineStage(symmetric=False))


def tracking_scale(config: Config) -> Config:
    """`config` with `FineStage.covariance_scale` = `TRACKING_COVARIANCE_SCALE` and
    `FineStage.covariance_noise` = inf (a constant factor; unchanged without a fine stage):
    the measurement covariance the tracker's filter was tuned with."""
    if config.fine is None:
        return config
    return eqx.tree_at(
        lambda c: (c.fine.covariance_scale, c.fine.covariance_noise), config, (TRACKING_COVARIANCE_SCALE, math.inf)
    )


def chain_estimates(
    clouds: Cloud,
    config: Config,
    key: PRNGKeyArray,
    keyframe_every: int = KEYFRAME_EVERY,
    guided: bool = True,
    keyframe_reach: float | None = KEYFRAME_REACH,
) -> Chain:
    """Register each frame against the current keyframe and chain the motions from frame 0.

    **Arguments:**

    - `clouds`: the frames (leading axis T; camera frame c, metres), e.g.
      `simulate_sequence(...).clouds`.
    - `config`: the estimate's [`jaxpose.Config`][] (its `max_points` must hold every frame).
    - `key`: frame k's estimate uses `fold_in(key, k)`.
    - `keyframe_every`: the most frames between keyframe switches; a switch happens only on a
      registered frame: the first one once it is due.
    - `keyframe_reach`: a switch is also due once the motion measured from the keyframe uses
      this fraction of the search box in any component (`motion_reached`); None: by frame
      count alone.
    - `guided`: pass each estimate the motion predicted at a constant rate
      (`predicted_motion`) as its `guess`, where its second surface fit starts instead of at
      rest (the keyframe's pose), which lies up to the keyframe's reach away. On by default:
      on the 40 tumbles of `experiments/tracking_benchmark.py` (two draws) it lowered the
      median rate error at 10 s from 0.095 to 0.062 °/s and the p90 from 0.438 to 0.322, at
      every noise level, and the largest rose from 0.885 to 1.397 (docs, Tracking).

    Motion continuity (`continuity_choice`, against the motion predicted at a constant rate)
    resolves an ambiguous estimate and accepts a weak one (low score, not converged, uncertain) that
    agrees with the prediction to within 1°, or to within the prediction's extrapolation error
    (`prediction_spread`, from the estimate's own covariance); such frames count as registered
    (`Chain.continuity`). The prediction is carried on at the rate from the keyframe before the
    current one to the last registered frame; when the frame before was refused, to an anchor
    at the last registered frame instead, which each registration moves `anchor_weight` of the
    way from the motion predicted there to the one registered (`anchored_motion`), so that one
    registration's error does not refuse every later frame.

    The registrations run with `Thresholds.min_rotation_lever` = 0 ([`registration_config`][]):
    continuity, not the single pair, judges a turn the faces leave to the outline.

    Pure and jittable (`lax.scan` over frames).
    """
    config = registration_config(config)
    first = jax.tree.map(lambda x: x[0], clouds)
    origin = plane_frame(first).origin  # O_n of frame 0: the tracked point
    eye = jnp.eye(3, dtype=origin.dtype)

    def step(carry, inputs):
        key_cloud, key_k, key_R, key_t, last_R, last_t, last_k, anchor, count, base_R, base_t, base_k = carry
        k, cloud = inputs
        problem = Problem.build(key_cloud, cloud, config)
        # After a refused frame (the last registered one is not k − 1) the prediction is carried
        # on from the anchor instead of the last registration, which may be the one in error.
        refused = last_k != k - 1
        source = tuple(jnp.where(refused, a, r) for a, r in zip(anchor, (last_R, last_t), strict=True))
        base, last = (base_R, base_t, base_k), (*source, last_k)
        R_pred, t_pred = predicted_motion(base, last, (key_R, key_t), k)
        guess = None
        if guided:  # static
            guess = displacement_from_motion(problem.frame.origin, problem.frame.axes, R_pred, t_pred)
        est = estimate_problem(problem, config, jax.random.fold_in(key, k), guess)
        spread = 0.0
        if est.covariance is not None:  # static: a config with a fine stage
            spread = prediction_spread(rotation_std(est.covariance), k, last_k, base_k)
        j, resolved = continuity_choice(est.hypotheses, est.status, R_pred, config, spread)
        H = est.hypotheses
        R_rel, t_rel = (
            jnp.where(resolved, H.rotation[j], est.rotation),
            jnp.where(resolved, H.translation[j], est.translation),
        )
        p = jnp.where(resolved, H.params[j], est.params)
        ok = (est.status == SUCCESS) | resolved
        R = jnp.where(ok, R_rel @ key_R, last_R)  # chain: frame 0 → keyframe → k
        t = jnp.where(ok, R_rel @ key_t + t_rel, last_t)
        if config.fine is None:
            cov = jnp.eye(6, dtype=origin.dtype) * 1e-4
        else:
            # Slot 0 of the hypotheses is the estimate, whose covariance the estimate carries;
            # only another hypothesis chosen by continuity needs its own.
            cov = jax.lax.cond(
                resolved & (j != 0), lambda: measurement_covariance(problem, config, p), lambda: est.covariance
            )
        usable = measurement_usable(R_rel, t_rel, cov)
        cov = jnp.where(ok & usable, cov, jnp.eye(6, dtype=origin.dtype))  # finite even when unused
        # A keyframe switch needs a usable measurement: the filter clones its state there.
        reached = motion_reached(p, config, keyframe_reach)
        switch = keyframe_switch(k, key_k, keyframe_every, ok & usable, reached)
        # The prediction's base: the keyframe before the current one (frame 0 until a switch).
        base_then = base
        base = tuple(jnp.where(switch, new, old) for new, old in zip((key_R, key_t, key_k), base, strict=True))
        key_cloud = tree_select(switch, cloud, key_cloud)
        key_k = jnp.where(switch, k, key_k)
        key_R, key_t = jnp.where(switch, R, key_R), jnp.where(switch, t, key_t)
        out = (R, t, R @ origin + t, est.status, R_rel, t_rel, cov, switch, resolved)
        count = count + ok.astype(count.dtype)
        weight = anchor_weight(count, k, last_k, base_then[2]).astype(t.dtype)
        predicted_here = predicted_motion(base_then, (*anchor, last_k), (eye, zeros), k)
        anchor = tuple(
            jnp.where(ok, new, old)
            for new, old in zip(anchored_motion(predicted_here, (R, t), weight), anchor, strict=True)
        )
        last_k = jnp.where(ok, k, last_k)
        return (key_cloud, key_k, key_R, key_t, R, t, last_k, anchor, count, *base), out

    zeros = jnp.zeros(3, origin.dtype)
    frames = jnp.arange(1, clouds.valid.shape[0])
    rest = jax.tree.map(lambda x: x[1:], clouds)
    start_k = jnp.asarray(0, frames.dtype)
    carry = (
        first,
        start_k,
        eye,
        zeros,
        eye,
        zeros,
        start_k,
        (eye, zeros),
        start_k,
        eye,
        zeros,
        start_k,
    )
    _, outs = jax.lax.scan(step, carry, (frames, rest))
    head = (eye, zeros, origin, jnp.asarray(SUCCESS, outs[3].dtype), eye, zeros, jnp.eye(6, dtype=origin.dtype))
    head = (*head, jnp.asarray(True), jnp.asarray(False))
    R, t, points, status, R_rel, t_rel, cov, switched, continuity = (
        jnp.concatenate([h[None], o]) for h, o in zip(head, outs, strict=True)
    )
    return Chain(R, t, points, status, origin, R_rel, t_rel, cov, switched, continuity)


def filter_chain(
    chain: Chain,
    dt: Float[ArrayLike, ""],
    rotation_sigma: float = 0.005,
    point_sigma: float = 0.005,
    rate_noise: Float[ArrayLike, ""] = 1e-4,
    accel_noise: Float[ArrayLike, ""] = 1e-4,
    spin_accel_noise: Float[ArrayLike, ""] = 1e-4,
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
        R, point, ok = inputs
        predicted = filt.predict(dt, rate_noise, accel_noise, spin_accel_noise).semidefinite()
        usable = measurement_usable(R, point, noise)
        updated = predicted.update(R, point, noise)
        filt, code = _guarded_update(filt, predicted, updated, ok, usable, predicted.innovation_ok(noise))
        return filt, (*_row(filt), code)

    filt = TrackFilter.start(chain.origin, spin_accel_sigma=spin_accel_sigma)
    ok = is_registered(chain.status, chain.continuity)
    _, outs = jax.lax.scan(step, filt, (chain.rotations[1:], chain.points[1:], ok[1:]))
    head = (*_row(filt), jnp.asarray(FILTER_UPDATED, jnp.int32))
    filtered = (jnp.concatenate([h[None], o]) for h, o in zip(head, outs, strict=True))
    return _track_of(chain, filtered)


def _track_of(chain: Chain, filtered) -> Track:
    """The `Track` of a chain and the filter's per-frame outputs (`_row`, then the status)."""
    return Track(
        chain.rotations,
        chain.points,
        chain.status,
        *filtered,
        keyframe_indices(chain.switched),
        chain.relative_cov,
        chain.continuity,
    )


def keyframe_indices(switched: Bool[Array, " T"]) -> Int[Array, " T"]:
    """For each frame k, the keyframe it was registered against: the last frame j < k that
    became a keyframe (`switched`); 0 for frame 0."""
    index = jnp.arange(switched.shape[0])
    last = jax.lax.cummax(jnp.where(switched, index, 0))
    return jnp.concatenate([jnp.zeros(1, last.dtype), last[:-1]])


def filter_keyframes(
    chain: Chain,
    dt: Float[ArrayLike, ""],
    rate_noise: Float[ArrayLike, ""] = 1e-4,
    accel_noise: Float[ArrayLike, ""] = 1e-2,
    spin_accel_noise: Float[ArrayLike, ""] = 1e-4,
    spin_accel_sigma: float = 0.01,
    shared_fraction: float = 0.5,
) -> Track:
    """Run the [`KeyframeFilter`][] over a chain: each successful frame's own estimate
    (keyframe → k, `chain.relative_*`) with its covariance (`chain.relative_cov`), the
    keyframe cloned where `chain.switched`. Same outputs and noise densities as
    [`filter_chain`][]. Pure and jittable.

    - `shared_fraction`: the part of each registration's covariance that all registrations
      against one keyframe share (the keyframe cloud's noise); it is carried by the clone,
      the rest is fused as independent noise. 0.5: both clouds are equally noisy.
    - `accel_noise` (m/s/√s) is 100× that of [`filter_chain`][]: the tracked point is not the
      centre of mass, so on a tumbling body it accelerates (ω² times its offset: ≈ 2.5 mm/s²
      for N5 at 4.5 °/s and 0.4 m). Here the translation measured is coupled to the rotation
      through the lever arm of the keyframe's point, so a motion model that cannot follow the
      point dragged the rate (`experiments/tumble_tracking.py`: 0.043–0.098 °/s after 10 s
      with 1e-4, against 0.010–0.046 with 1e-2, over six seeds).
    """

    def step(filt, inputs):
        R_rel, t_rel, cov, ok, switched = inputs
        predicted = filt.predict(dt, rate_noise, accel_noise, spin_accel_noise).semidefinite()
        usable = measurement_usable(R_rel, t_rel, cov)
        cov = jnp.where(usable, cov, jnp.eye(6, dtype=cov.dtype))  # the update is computed, then discarded
        noise = (1 - shared_fraction) * cov
        updated = predicted.update(R_rel, t_rel, noise)
        filt, code = _guarded_update(filt, predicted, updated, ok, usable, predicted.innovation_ok(noise))
        # The chain switched keyframes: later measurements are against the new one, so the
        # clone follows it whether or not this frame's update was kept.
        filt = tree_select(switched, filt.clone(shared_fraction * cov).semidefinite(), filt)
        return filt, (*_row(filt.now), code)

    # Frame 0 is the first keyframe: its share comes with the first registration's covariance
    # (none where that one is unusable).
    filt = KeyframeFilter.start(chain.origin, spin_accel_sigma=spin_accel_sigma)
    first = chain.relative_cov[1]
    first_ok = measurement_usable(chain.relative_rotations[1], chain.relative_translations[1], first)
    filt = filt.clone(shared_fraction * jnp.where(first_ok, first, 0.0))
    ok = is_registered(chain.status, chain.continuity)
    inputs = (chain.relative_rotations, chain.relative_translations, chain.relative_cov, ok, chain.switched)
    _, outs = jax.lax.scan(step, filt, jax.tree.map(lambda x: x[1:], inputs))
    head = (*_row(filt.now), jnp.asarray(FILTER_UPDATED, jnp.int32))
    filtered = (jnp.concatenate([h[None], o]) for h, o in zip(head, outs, strict=True))
    return _track_of(chain, filtered)


def _row(filt: TrackFilter):
    # A usable covariance's diagonal can be negative by round-off (`PSD_TOL`): zero, not NaN.
    std = jnp.sqrt(jnp.maximum(jnp.diag(filt.cov)[ERR_RATE], 0.0))
    return filt.attitude, filt.rate, filt.spin_accel, filt.position, filt.velocity, std


def track(
    clouds: Cloud,
    dt: Float[ArrayLike, ""],
    config: Config | None = None,
    key: PRNGKeyArray | None = None,
    keyframe_every: int = KEYFRAME_EVERY,
    guided: bool = True,
    keyframe_reach: float | None = KEYFRAME_REACH,
    **filter_options,
) -> Track:
    """Track a sequence of clouds: `chain_estimates` then `filter_keyframes`.

    **Arguments:**

    - `clouds`: one [`jaxpose.Cloud`][] with a leading time axis T (camera frame c, metres).
    - `dt`: seconds between frames.
    - `config`: the estimate's [`jaxpose.Config`][] (default `default_tracking_config()`:
      `Config()` with one-way fine-stage residuals). At the Python boundary capacities left
      at None are sized from the whole sequence (any frame may become the keyframe); under
      jit from the clouds' row counts.
    - `key`: PRNG key of the searches (required).
    - `keyframe_every`, `keyframe_reach`: when the keyframe switches (see `chain_estimates`).
    - `guided`: registrations guided by the motion predicted at a constant rate (see
      `chain_estimates`); on by default.
    - `filter_options`: go to `filter_keyframes`.

    **Returns:**

    A [`Track`][jaxpose.Track]; every filtered output is finite, and `filter_status` says which frames were
    fused. Pure and jittable; at the Python boundary the whole run is one compiled program per
    capacity bucket.
    """
    if key is None:
        raise ValueError("track needs a PRNG key: track(clouds, dt, key=jax.random.key(0)).")
    config = default_tracking_config() if config is None else config
    if not is_concrete(clouds):
        return _track(clouds, jnp.asarray(dt), config, key, keyframe_every, guided, keyframe_reach, filter_options)
    _check_sequence(clouds, dt)
    clouds = clouds.floating()  # the session's float dtype: float32 or integer points reuse its program
    config = sized_sequence_config(clouds, config)
    dtype = clouds.points.dtype
    return _track_program(
        clouds, jnp.asarray(dt, dtype), config, key, keyframe_every, guided, keyframe_reach, filter_options
    )


def _check_sequence(clouds: Cloud, dt) -> None:
    """Clear errors at the Python boundary for a sequence that cannot be tracked."""
    points = np.asarray(clouds.points)
    if points.ndim != 3 or points.shape[-1] != 3 or points.shape[0] < 2:
        raise ValueError(f"clouds: expected points of shape (T ≥ 2, N, 3), got {points.shape}.")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}.")
    for k in range(points.shape[0]):
        jax.tree.map(lambda x, k=k: x[k], clouds).check(f"frame {k}")


def _track(clouds, dt, config, key, keyframe_every, guided, keyframe_reach, filter_options) -> Track:
    chain = chain_estimates(clouds, config, key, keyframe_every, guided, keyframe_reach)
    return filter_keyframes(chain, dt, **filter_options)


_track_program = BoundedJit(_track)
"""Registration and filter over a whole sequence as one compiled program per capacity bucket."""


__all__ = [
    "TRACKING_COVARIANCE_SCALE",
    "default_tracking_config",
    "FILTER_STATUS_NAME",
    "Chain",
    "KeyframeFilter",
    "Track",
    "TrackFilter",
    "chain_estimates",
    "filter_chain",
    "filter_keyframes",
    "keyframe_switch",
    "motion_reached",
    "measurement_covariance",
    "measurement_usable",
    "nearest_semidefinite",
    "track",
]
