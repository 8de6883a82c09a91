"""Registration of every frame against a growing body-frame model (issue 24).

A keyframe chain ([`jaxpose.track`][]) registers frame k against one earlier frame, its
keyframe, and chains the motions: each keyframe switch adds that pair's error to every later
frame (the attitude drifts), and every frame registered against one keyframe shares that
keyframe cloud's range noise (the error the keyframes share, which sets the floor of
[`jaxpose.identify`][]).

[`track_against_model`][jaxpose.track_against_model] registers each frame against the
**model** instead: the keyframes registered so far, carried back to the first frame's time
by their motions and averaged per voxel (`jaxpose.tracking._model.fuse_clouds`). It walks the
chain's keyframes in order; keyframe j's frames (those the chain registered against it, the
next keyframe among them) are registered against the model of keyframes 0 … j, so the
next keyframe enters the model at a motion measured against all the surface seen so far,
not against one noisy view. A surface seen again later (a tumble that turns a face back
into view) is matched against every earlier view of it.

**One registration** ([`register_frame`][]): the fine stage alone (`jaxpose._fine.fine_refine`,
the default point-to-plane fit), first from the motion of the last registrations carried on at
their rate (`_predicted_start`), and where that fit is no success, from the chain's own
measurement keyframe → k composed with the keyframe's model-registered motion
(`_chain_start`). A fit that stays weak (not converged, or uncertain) but lies within 1° of
the chain's own registration of the frame counts too (`agrees_with_chain`): under 2 cm of
range noise every fit can be weak. No pattern search: the chain has already resolved the
motion to within its drift, inside the fine stage's basin. The rate's start comes first:
between frames a few tens of milliseconds apart it is closer than the chain's, which carries
the chain's own registration errors. The model's fine side ([`model_side`][]) is built once
per keyframe, in the model's own plane frame, with `MODEL_POINTS` previous points (the model
shows every side; a frame's view shows about half of them).

**Frames** (camera frame c, metres): the motion from the first frame to frame k is
x ↦ R_0k x + t_0k, as in [`jaxpose.Track`][].
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._checks import is_concrete
from .._cloud import Cloud
from .._config import Config
from .._estimate import LOW_SCORE, NON_FINITE, NOT_CONVERGED, SUCCESS, UNCERTAIN, is_uncertain
from .._fine import CurrentSide, FineCloud, back_side, current_side, fine_cloud, fine_refine
from .._frame import PlaneFrame, plane_frame
from .._poses import displacement_from_motion, motion_from_displacement
from .._problem import _current_points, sized_sequence_config
from .._rotations import rotation_angle
from .._uncertainty import motion_covariance
from ._model import into_model_frame, voxel_means
from ._track import (
    WEAK_FRACTION,
    Chain,
    Track,
    default_tracking_config,
    filter_keyframes,
    is_registered,
    measurement_usable,
    predicted_motion,
    tracking_scale,
)

MODEL_POINTS = 16384
"""Previous points of the model's fine side (`FineStage.prev_points` for the model): the model
shows every side of the target, a frame about half, so about twice a frame's 4096 points keep
the sampling of the surface a frame sees."""

MIN_INLIERS = 0.5
"""Fewest of a frame's selected points within `FineStage.inlier` of the model for its
registration to count (a view mostly of surface the model has not seen is not registered:
it keeps its start and the filter does not fuse it)."""

MODEL_VOXEL = 0.01
"""Default voxel edge of the model (m): about a ToF pixel's footprint at 5–6 m."""


class ModelSide(eqx.Module):
    """The model as the previous side of a registration: its plane frame n (any frame serves
    the fine stage; the model's own keeps the coordinates small) and its fine-stage surface
    (`FineCloud`, frame n)."""

    frame: PlaneFrame
    fine: FineCloud


class _ModelProblem(eqx.Module):
    """A `jaxpose._fine.SurfaceProblem`: the fields of a `Problem` that the fine stage and its
    covariance read. The model's side, the current cloud in frame n (`curr`, SoA, and
    `curr_valid`), the smoothed current side and the current side's planes if the config asks
    for them, and the cutting planes' geometry (`d`, `planes`; the slabs are the whole surface
    by default)."""

    frame: PlaneFrame
    fine: FineCloud
    d: Float[Array, ""]
    curr: Float[Array, "3 M"]
    curr_valid: Bool[Array, " M"]
    fine_curr: CurrentSide | None
    fine_back: FineCloud | None
    planes: tuple = eqx.field(static=True)


class FrameRegistration(eqx.Module):
    """One frame registered against the model: the motion from the first frame (`rotation`
    R_0k, `translation` t_0k, frame c, metres), its `status` (the `jaxpose.Status` codes:
    success, not converged, low score for too few inliers, non-finite, uncertain), its
    covariance (6, 6; a left rotation vector in rad, then metres, as `Track.measurement_cov`)
    and the fraction of its points within the inlier distance of the model. A leading axis T:
    every frame of a sequence."""

    rotation: Float[Array, "*batch 3 3"]
    translation: Float[Array, "*batch 3"]
    status: Int[Array, "*batch"]
    covariance: Float[Array, "*batch 6 6"]
    inliers: Float[Array, "*batch"]


def model_config(config: Config, model_points: int = MODEL_POINTS) -> Config:
    """`config` with the fine stage's previous side set to `model_points` points (static), and
    the covariance scale of the tracker's registrations (`tracking_scale`)."""
    if config.fine is None:
        raise ValueError("registration against the model needs the fine stage (Config.fine is None).")
    return tracking_scale(dataclasses.replace(config, fine=dataclasses.replace(config.fine, prev_points=model_points)))


@eqx.filter_jit
def model_side(points: Float[Array, "M 3"], valid: Bool[Array, " M"], config: Config) -> ModelSide:
    """The model's fine side from its points (frame c at the first frame's time, metres) and
    their mask. Pure and jittable."""
    frame = plane_frame(Cloud(points, valid))
    A = frame.to_frame(points)
    d = jnp.asarray(config.patterns.d, A.dtype)
    return ModelSide(frame, fine_cloud(A, valid, config, config.patterns.planes(), d))


@eqx.filter_jit
def register_frame(
    side: ModelSide, cloud: Cloud, rotation: Float[Array, "3 3"], translation: Float[Array, "3"], config: Config
) -> FrameRegistration:
    """Fit frame k's cloud (frame c) to the model with the fine stage from the starting motion
    (`rotation`, `translation`: first frame → k, frame c, metres). Pure and jittable."""
    frame = side.frame
    dtype = side.fine.points.dtype
    curr, curr_valid, _ = _current_points(frame, cloud, config, dtype)
    problem = _ModelProblem(
        frame=frame,
        fine=side.fine,
        d=jnp.asarray(config.patterns.d, dtype),
        curr=curr,
        curr_valid=curr_valid,
        fine_curr=current_side(curr, curr_valid, config),
        fine_back=back_side(
            curr, curr_valid, config, config.patterns.planes(), jnp.asarray(config.patterns.d, dtype), side.fine.noise
        ),
        planes=config.patterns.planes(),
    )
    start = displacement_from_motion(frame.origin, frame.axes, rotation.astype(dtype), translation.astype(dtype))
    fit = fine_refine(problem, config, start)
    finite = jnp.all(jnp.isfinite(fit.params))
    p = jnp.where(finite, fit.params, start)
    R, t = motion_from_displacement(frame.origin, frame.axes, p)
    cov = motion_covariance(problem, config, p)
    status = jnp.where(
        ~finite,
        NON_FINITE,
        jnp.where(
            fit.inliers < MIN_INLIERS,
            LOW_SCORE,
            jnp.where(is_uncertain(cov, config), UNCERTAIN, jnp.where(fit.converged, SUCCESS, NOT_CONVERGED)),
        ),
    )
    return FrameRegistration(R, t, status.astype(jnp.int32), cov, fit.inliers)


@jax.jit
def _fused(
    points: Float[Array, "F P 3"],
    valid: Bool[Array, "F P"],
    rotations: Float[Array, "F 3 3"],
    translations: Float[Array, "F 3"],
    included: Bool[Array, " F"],
    voxel: Float[ArrayLike, ""],
) -> tuple[Float[Array, "FP 3"], Bool[Array, " FP"]]:
    """The model of the `included` frames (frame c at the first frame's time): their points
    carried back by their motions and averaged per voxel, at a fixed size (F·P rows, the
    occupied voxels first), so that every keyframe's model shares one compiled program."""
    eye, zero = jnp.eye(3, dtype=points.dtype), jnp.zeros(3, points.dtype)
    moved = into_model_frame(points, rotations, translations, eye, zero)
    live = valid & included[:, None]
    means, counts = voxel_means(moved.reshape(-1, 3), live.reshape(-1), voxel)
    return means, counts > 0


BASELINE = 5
"""Frames between the two registrations whose screw motion, carried on at a constant rate,
predicts the next frame's motion (the first start of each registration)."""


def _chain_start(chain_R, chain_t, j, k, R_key, t_key):
    """The chain's measurement keyframe j → k composed with the keyframe's motion from frame 0."""
    R_rel = chain_R[k] @ chain_R[j].T
    return R_rel @ R_key, R_rel @ t_key + (chain_t[k] - R_rel @ chain_t[j])


def _predicted_start(R, t, done: list[int], k: int):
    """The motion first frame → k at the constant rate of the registrations `done[-1]` and the
    one `BASELINE` registrations before it (frame 0 alone: no motion)."""
    a, b = done[max(len(done) - 1 - BASELINE, 0)], done[-1]
    R_k, t_k = _predicted(R[a], t[a], R[b], t[b], np.asarray([a, b, k]))
    return np.asarray(R_k), np.asarray(t_k)


@jax.jit
def _predicted(R_a, t_a, R_b, t_b, frames: Int[Array, "3"]):
    eye, zero = jnp.eye(3, dtype=R_a.dtype), jnp.zeros(3, t_a.dtype)
    return predicted_motion((R_a, t_a, frames[0]), (R_b, t_b, frames[1]), (eye, zero), frames[2])


def track_against_model(
    clouds: Cloud,
    track: Track,
    dt: Float[ArrayLike, ""],
    config: Config | None = None,
    *,
    voxel: float = MODEL_VOXEL,
    model_points: int = MODEL_POINTS,
    **filter_options,
) -> Track:
    """Register every frame of a tracked sequence against the body-frame model of the keyframes
    seen so far, and filter the result (see the module docstring).

    **Arguments:**

    - `clouds`: the [`jaxpose.Cloud`][] with a leading time axis T that `jp.track` took
      (camera frame c, metres).
    - `track`: what `jp.track(clouds, dt, ...)` returned: its keyframes set the model's
      frames and its measurements the starts.
    - `dt`: seconds between frames.
    - `config`: the [`jaxpose.Config`][] of the fine stage (default
      `default_tracking_config()`: `Config()` with one-way residuals, as the chain's
      registrations); capacities left at None are sized from the clouds.
    - `voxel`: the model's voxel edge (m).
    - `model_points`: points of the model's fine side (`MODEL_POINTS`).
    - `filter_options`: go to `filter_keyframes`.

    **Returns:** a [`jaxpose.Track`][] whose measurements are first frame → k, all against the
    model (so `keyframes` is 0 for every frame and `rotations` are the registrations
    themselves, not a chain); `status` is each registration's (`FrameRegistration`);
    `continuity` marks the weak registrations accepted because they agree with the chain's
    (`agrees_with_chain`); `registered()` is a success or such a frame. Any other frame
    keeps its start and is not fused by the filter.

    Not better for `jp.identify` than the chain's track: its errors are the model's slow
    drift, shared by many frames; `identify`'s split check raises the covariance for it (on
    the tumbles of `experiments/model_tracking.py` none was reported observable), but the
    estimates are no closer (docs, Tracking). Identify the chain's track.

    Python boundary: a loop over the keyframes, each a model built and its frames registered
    by compiled programs (one per capacity bucket).
    """
    if not isinstance(track, Track):
        raise ValueError(f"track_against_model needs the Track that jp.track returns, got {type(track).__name__}.")
    if not is_concrete(clouds, track):
        raise ValueError("track_against_model runs at the Python boundary (a loop over keyframes), not under jit.")
    T = track.rotations.shape[0]
    if clouds.points.ndim != 3 or clouds.points.shape[0] != T:
        raise ValueError(f"clouds must have the track's leading time axis of {T} frames, got {clouds.points.shape}.")
    if not (np.isfinite(voxel) and voxel > 0):
        raise ValueError(f"voxel must be a positive number of metres, got {voxel!r}.")
    config = model_config(
        sized_sequence_config(clouds, default_tracking_config() if config is None else config), model_points
    )
    registrations, agreed = _register_all(clouds, track, config, voxel)
    return _filtered(track, registrations, agreed, dt, filter_options)


def _register_all(
    clouds: Cloud, track: Track, config: Config, voxel: float
) -> tuple[FrameRegistration, Bool[Array, " T"]]:
    """Walk the chain's keyframes in order: model of the keyframes 0 … j that registered, then
    keyframe j's frames registered against it, each from the last registrations' rate carried
    on (`_predicted_start`) and, where that fit is no success, again from the chain's
    measurement composed with keyframe j's motion (`_chain_start`; frame 0's own where the
    chain lost the frame). A fit that is weak (not converged or uncertain) but agrees with the
    chain's registration of the frame (`agrees_with_chain`) is accepted as well. Returns every
    frame's registration (frame 0: the identity) and which frames were accepted by that
    agreement."""
    T = track.rotations.shape[0]
    chain_R, chain_t = np.asarray(track.rotations), np.asarray(track.motions()[0])
    keyframes, registered = np.asarray(track.keyframes), np.asarray(track.registered())
    order = [0] + [int(j) for j in np.unique(keyframes) if j > 0 and registered[j]]
    size = config.capacities.max_points
    models = jax.vmap(lambda c: c.packed(size))(jax.tree.map(lambda x: x[np.asarray(order)], clouds))
    model_points, model_valid = models.points, models.valid
    dtype = model_points.dtype
    R = np.tile(np.eye(3, dtype=dtype), (T, 1, 1))
    t = np.zeros((T, 3), dtype)
    status = np.full(T, NOT_CONVERGED, np.int32)
    status[0] = SUCCESS
    agreed = np.zeros(T, bool)
    # Frame 0's measurement (the identity, against itself) carries the chain's unit covariance:
    # it tells nothing, and `identify` must not weight it.
    cov = np.tile(np.eye(6, dtype=dtype), (T, 1, 1))
    inliers = np.ones(T, dtype)
    done = [0]  # the frames registered against the model, in order
    for s, j in enumerate(order):
        # Only keyframes that registered against the model enter it (frame 0 is its anchor).
        counted = np.asarray(is_registered(jnp.asarray(status[order]), jnp.asarray(agreed[order])))
        included = counted & (np.arange(len(order)) <= s)
        pts, live = _fused(model_points, model_valid, R[order], t[order], included, voxel)
        side = model_side(pts, live, config)
        for k in (int(k) for k in np.nonzero(keyframes == j)[0] if k != 0):
            cloud = jax.tree.map(lambda x, k=k: x[k], clouds)
            by_rate = _predicted_start(R, t, done, k)
            reg = register_frame(side, cloud, *by_rate, config)
            if int(reg.status) != SUCCESS:
                by_chain = _chain_start(chain_R, chain_t, j, k, R[j], t[j]) if registered[k] else (R[0], t[0])
                again = register_frame(side, cloud, *by_chain, config)
                if int(again.status) == SUCCESS:
                    reg = again
                elif registered[k]:
                    for candidate in (again, reg):
                        if agrees_with_chain(candidate, by_chain[0], config):
                            reg, agreed[k] = candidate, True
                            break
            status[k], inliers[k] = int(reg.status), float(reg.inliers)
            cov[k] = np.asarray(reg.covariance)
            if status[k] == SUCCESS or agreed[k]:
                R[k], t[k] = np.asarray(reg.rotation), np.asarray(reg.translation)
                done.append(k)
            else:
                R[k], t[k] = by_rate
    registrations = FrameRegistration(
        jnp.asarray(R), jnp.asarray(t), jnp.asarray(status), jnp.asarray(cov), jnp.asarray(inliers)
    )
    return registrations, jnp.asarray(agreed)


def agrees_with_chain(reg: FrameRegistration, chain_rotation: np.ndarray, config: Config) -> bool:
    """Whether a weak registration against the model (not converged or uncertain, with a usable
    covariance) lies within `WEAK_FRACTION` × `Thresholds.ambiguous_deg` of the chain's
    registration of the same frame (`chain_rotation`, first frame → k, camera frame c).

    Two registrations of one frame found independently (the chain's by a search against one
    keyframe, this one by a fit against the model) that agree are evidence of the motion as
    the chain's motion continuity is: under 2 cm of range noise every estimate of a frame can
    be weak (Chibis-M and the fragment of the tracking benchmark, whose chains register every
    frame by continuity), and accepting only successes left those tracks with no frame fused
    against the model. The filter weighs the accepted frame by its own covariance."""
    weak = int(reg.status) in (NOT_CONVERGED, UNCERTAIN)
    usable = bool(measurement_usable(reg.rotation, reg.translation, reg.covariance))
    gate = np.radians(WEAK_FRACTION * config.thresholds.ambiguous_deg)
    return bool(weak and usable and float(rotation_angle(reg.rotation, jnp.asarray(chain_rotation))) <= gate)


def _filtered(track: Track, reg: FrameRegistration, agreed: Bool[Array, " T"], dt, filter_options) -> Track:
    """The registrations as a chain anchored at frame 0 (every frame its own measurement,
    frame 0 the only keyframe; the weak ones that agreed with the chain as `continuity`),
    through `filter_keyframes`."""
    T = reg.rotation.shape[0]
    origin = track.points[0]
    usable = jax.vmap(measurement_usable)(reg.rotation, reg.translation, reg.covariance)
    cov = jnp.where(usable[:, None, None], reg.covariance, jnp.eye(6, dtype=reg.covariance.dtype))
    chain = Chain(
        rotations=reg.rotation,
        translations=reg.translation,
        points=jnp.einsum("tij,j->ti", reg.rotation, origin) + reg.translation,
        status=reg.status,
        origin=origin,
        relative_rotations=reg.rotation,
        relative_translations=reg.translation,
        relative_cov=cov,
        switched=jnp.arange(T) == 0,
        continuity=agreed,
    )
    return filter_keyframes(chain, jnp.asarray(dt, reg.rotation.dtype), **filter_options)


__all__ = [
    "MIN_INLIERS",
    "MODEL_POINTS",
    "MODEL_VOXEL",
    "FrameRegistration",
    "agrees_with_chain",
    "ModelSide",
    "model_config",
    "model_side",
    "register_frame",
    "track_against_model",
]
