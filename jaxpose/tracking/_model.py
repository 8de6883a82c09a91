"""A body-frame model of the target: the registered clouds fused into one voxelised cloud.

A tracked tumble shows the target from many sides. Carried back by the tracked motions into
one frame, the clouds' points pile up on the target's surface; averaged per voxel, they give
a model of its shape, denser and less noisy than any single view.

**Frames.** The measured motion from the first frame to frame k is x ↦ R_k x + t_k in the
camera frame c (metres), so a point x seen at frame k was at R_kᵀ (x − t_k) at the first
frame's time. With identified dynamics, the model is written in the body's principal frame
b: y = Pᵀ (x₀ − c), with P = `Dynamics.principal_axes` (columns J1 ≤ J2 ≤ J3) and c =
`Dynamics.centre`, both in frame c at the first frame's time. Without them it stays in
frame c at the first frame's time.

**Which frames.** By default the keyframes: every frame of a track was registered against
one, so they carry the least accumulated error (one registration each), they are spread over
the tumble by motion (`keyframe_reach`), and there are few of them (tens per minute), which
keeps the fusion small (a frame is a whole sensor image of points).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._cloud import Cloud
from ._identify import Dynamics
from ._track import Track

MIN_POINTS = 2
"""Fewest points a voxel needs to enter the model: a voxel hit once is as likely a flying
pixel or a stray return as surface."""


def into_model_frame(
    points: Float[Array, "F N 3"],
    rotations: Float[Array, "F 3 3"],
    translations: Float[Array, "F 3"],
    axes: Float[Array, "3 3"],
    centre: Float[Array, "3"],
) -> Float[Array, "F N 3"]:
    """Each frame's points carried back to the first frame's time, y = Pᵀ (R_kᵀ (x − t_k) − c)
    (metres; frame b for principal `axes` P and centre c, frame c for P = I, c = 0)."""
    back = jnp.einsum("fji,fnj->fni", rotations, points - translations[:, None, :])
    return jnp.einsum("ji,fnj->fni", axes, back - centre[None, None, :])


@jax.jit
def voxel_means(
    points: Float[Array, "M 3"], valid: Bool[Array, " M"], voxel: Float[ArrayLike, ""]
) -> tuple[Float[Array, "M 3"], Int[Array, " M"]]:
    """Points averaged per cubic voxel of edge `voxel` (m): the voxels' mean points and their
    counts, the occupied voxels first (counts 0 after them). Pure and jittable: the voxels are
    found by sorting the points' integer cells (lexicographic), so no grid size is needed."""
    cells = jnp.floor(points / voxel).astype(jnp.int32)
    big = jnp.iinfo(jnp.int32).max
    cells = jnp.where(valid[:, None], cells, big)  # invalid points sort last, in a cell of their own
    order = jnp.lexsort((cells[:, 2], cells[:, 1], cells[:, 0]))
    sorted_cells, sorted_points, sorted_valid = cells[order], points[order], valid[order]
    new = jnp.concatenate([jnp.ones(1, bool), jnp.any(sorted_cells[1:] != sorted_cells[:-1], axis=1)])
    segment = jnp.cumsum(new) - 1
    m = points.shape[0]
    weight = sorted_valid.astype(points.dtype)
    sums = jax.ops.segment_sum(sorted_points * weight[:, None], segment, num_segments=m)
    counts = jax.ops.segment_sum(sorted_valid.astype(jnp.int32), segment, num_segments=m)
    return sums / jnp.maximum(counts, 1)[:, None], counts


def body_model(
    clouds: Cloud,
    track: Track,
    dynamics: Dynamics | None = None,
    voxel: float = 0.01,
    frames: Int[ArrayLike, " F"] | None = None,
    min_points: int = MIN_POINTS,
) -> Cloud:
    """Fuse a tracked sequence's clouds into one voxelised model of the target.

    **Arguments:**

    - `clouds`: the [`jaxpose.Cloud`][] with a leading time axis that `jp.track` took.
    - `track`: what `jp.track(clouds, dt, ...)` returned.
    - `dynamics`: what `jp.identify(track, dt)` returned: the model is then in the body's
      principal frame b, centred on the centre of mass. None: frame c at the first frame's
      time.
    - `voxel`: voxel edge (m).
    - `frames`: the frames to fuse (default: the registered keyframes, frame 0 included).
    - `min_points`: fewest points for a voxel to count.

    **Returns:** a `Cloud` of the voxels' mean points (m), valid where a voxel holds at least
    `min_points` points; sized from the data. Save it with `jp.save_cloud("model.ply", ...)`.

    Raises `ValueError` when the clouds and the track disagree in length, for a voxel that is
    not a positive number, or when no frame is registered.
    """
    if not isinstance(track, Track):
        raise ValueError(f"body_model needs the Track that jp.track returns, got {type(track).__name__}.")
    points, valid = jnp.asarray(clouds.points), jnp.asarray(clouds.valid)
    T = track.rotations.shape[0]
    if points.ndim != 3 or points.shape[0] != T:
        raise ValueError(f"clouds must have the track's leading time axis of {T} frames, got shape {points.shape}.")
    if not (np.isfinite(voxel) and voxel > 0):
        raise ValueError(f"voxel must be a positive number of metres, got {voxel!r}.")
    registered = np.array(track.registered())
    registered[0] = True  # the first frame is the reference: its motion is the identity
    if frames is None:
        frames = np.unique(np.concatenate([[0], np.asarray(track.keyframes)]))
    frames = np.asarray(frames, int)
    frames = frames[registered[frames]]
    translations, finite = track.motions()
    frames = frames[np.asarray(finite)[frames]]
    rotations, translations = jnp.asarray(track.rotations)[frames], translations[frames]
    if frames.size == 0:
        raise ValueError("body_model needs at least one registered frame with a finite motion.")
    if dynamics is None:
        axes, centre = jnp.eye(3, dtype=points.dtype), jnp.zeros(3, points.dtype)
    else:
        axes, centre = dynamics.principal_axes, dynamics.centre
    return fuse_clouds(points[frames], valid[frames], rotations, translations, axes, centre, voxel, min_points)


def fuse_clouds(
    points: Float[ArrayLike, "F N 3"],
    valid: Bool[ArrayLike, "F N"],
    rotations: Float[ArrayLike, "F 3 3"],
    translations: Float[ArrayLike, "F 3"],
    axes: Float[ArrayLike, "3 3"],
    centre: Float[ArrayLike, "3"],
    voxel: float,
    min_points: int = MIN_POINTS,
) -> Cloud:
    """The core of [`body_model`][jaxpose.body_model]: frames' points (frame c, m) with their
    motions from the first frame (x ↦ R x + t), carried into the model frame
    (`into_model_frame`) and averaged per voxel; the voxels with at least `min_points` points,
    as a `Cloud` sized from the data."""
    points = jnp.asarray(points)
    moved = into_model_frame(
        points,
        jnp.asarray(rotations, points.dtype),
        jnp.asarray(translations, points.dtype),
        jnp.asarray(axes, points.dtype),
        jnp.asarray(centre, points.dtype),
    )
    means, counts = voxel_means(moved.reshape(-1, 3), jnp.asarray(valid).reshape(-1), voxel)
    keep = np.asarray(counts) >= min_points
    return Cloud.from_points(np.asarray(means)[keep])


__all__ = ["MIN_POINTS", "body_model", "fuse_clouds", "into_model_frame", "voxel_means"]
