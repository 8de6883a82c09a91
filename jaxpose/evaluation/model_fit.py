"""Known-model baseline (issue 7, the Chibis-M report's approach transposed to lidar).

When the target's shape is known (a [`jaxpose.targets.Boxes`][]), its pose in one cloud is
found by least squares: each valid point, moved into the target frame by the candidate pose,
should lie on the model's surface, so its residual is the signed distance to the union of
boxes. optimistix's Levenberg–Marquardt minimises the sum of squares over the pose
(rotation vector and translation, applied on the left of a starting pose). A local method:
it needs a starting pose within its convergence region. The motion between two clouds is
then the composition of the two fitted poses.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import optimistix as optx
from jaxtyping import Array, Float

from .._cloud import Cloud
from ..sim.targets import Boxes


def box_distance(points: Float[Array, "N 3"], boxes: Boxes) -> Float[Array, " N"]:
    """Signed distance (m) of points in the target frame t to the surface of a union of boxes
    (negative inside): the minimum over boxes of each box's exact signed distance."""

    def one(center, half, rotation):
        local = (points - center[None]) @ rotation  # box frame
        q = jnp.abs(local) - half[None]
        sq = jnp.sum(jnp.maximum(q, 0.0) ** 2, axis=-1)
        outside = jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)  # finite gradient at 0
        inside = jnp.minimum(jnp.max(q, axis=-1), 0.0)
        return outside + inside

    return jnp.min(jax.vmap(one)(boxes.centers, boxes.half_sizes, boxes.rotations), axis=0)


class ModelFit(eqx.Module):
    """Fitted pose G^c_t (`rotation`), O_t in frame c (`translation`, m), the RMS surface
    distance of the valid points (m), and whether LM converged."""

    rotation: Float[Array, "3 3"]
    translation: Float[Array, "3"]
    rms: Float[Array, ""]
    converged: Array


@eqx.filter_jit
def fit_model(cloud: Cloud, model: Boxes, R0, t0, max_steps: int = 100) -> ModelFit:
    """Pose of `model` in `cloud` (camera frame c, metres) by Levenberg–Marquardt from (R0, t0).

    Residuals: signed distance of each valid point x, taken to the target frame as
    Rᵀ (x − t), to the model surface; invalid points contribute 0. The update is a rotation
    vector ω and a shift δ on the left: R = exp(ω) R0, t = t0 + δ. Pure and jittable.
    """
    x, valid = cloud.masked_points, cloud.valid
    R0, t0 = jnp.asarray(R0, x.dtype), jnp.asarray(t0, x.dtype)

    def pose(y):
        return jaxlie.SO3.exp(y[:3]).as_matrix() @ R0, t0 + y[3:]

    def residuals(y, _):
        R, t = pose(y)
        return jnp.where(valid, box_distance((x - t[None]) @ R, model), 0.0)

    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10)
    result = optx.least_squares(residuals, solver, jnp.zeros(6, x.dtype), None, max_steps=max_steps, throw=False)
    R, t = pose(result.value)
    r = residuals(result.value, None)
    rms = jnp.sqrt(jnp.sum(r * r) / jnp.maximum(jnp.sum(valid), 1))
    return ModelFit(R, t, rms, result.result == optx.RESULTS.successful)


__all__ = ["ModelFit", "box_distance", "fit_model"]
