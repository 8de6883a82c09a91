"""The plane frame n of a cloud: centroid and principal axes of its inertia tensor.

DECISIONS.md "Plane frame n": O_n = centroid of the valid points; J = tr(C)·I − C with the
scatter matrix C = Σ (g − O_n)(g − O_n)ᵀ; J = U D Uᵀ with D descending, so n1 is the axis of
**least** spread and plane 1 (normal n1) cuts the cloud along its two largest extents.
J is symmetric positive semidefinite, so its SVD is its eigendecomposition; we use `eigh`
(METHOD.md D4). Signs: n1 and n2 are flipped so that their component of largest magnitude is
positive, then n3 = n1 × n2, so G^c_n = [n1 n2 n3] is a proper rotation.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ._cloud import Cloud

MIN_POINTS = 10
"""Fewest valid points a previous cloud may have."""

AMBIGUITY_TOL = 1e-6
"""Two inertia eigenvalues closer than this (relative to the largest) make the axes ambiguous."""

FLATNESS_TOL = 1e-6
"""A scatter eigenvalue below this fraction of the largest counts as zero spread. Only a
collinear cloud (two zero spreads) is flat: a coplanar one (one face of a box seen head-on)
has three distinct inertia eigenvalues, so its frame is defined (DECISIONS.md: degenerate
means equal eigenvalues or fewer than 3 non-collinear points), and the face's outline fixes
the motion within its plane."""

FRAME_OK, FRAME_TOO_FEW_POINTS, FRAME_FLAT, FRAME_AMBIGUOUS = 0, 1, 2, 3
FRAME_STATUS_TEXT = {
    FRAME_OK: "ok",
    FRAME_TOO_FEW_POINTS: f"fewer than {MIN_POINTS} valid points",
    FRAME_FLAT: "the points are collinear (zero spread across a line)",
    FRAME_AMBIGUOUS: "two principal spreads are equal, so the plane axes are ambiguous",
}


class PlaneFrame(eqx.Module):
    """The frame n of the cutting planes, in the camera frame c.

    **Fields:**

    - `origin`: O_n, the centroid of the valid points, metres, frame c.
    - `axes`: G^c_n, `(3, 3)`, columns n1 n2 n3 (least → largest spread) in frame c.
    - `inertia`: eigenvalues of J in descending order (m²).
    - `num_points`: number of valid points used.
    - `status`: 0 ok, 1 too few points, 2 flat (collinear), 3 ambiguous axes;
      see `FRAME_STATUS_TEXT`.
    """

    origin: Float[Array, "3"]
    axes: Float[Array, "3 3"]
    inertia: Float[Array, "3"]
    num_points: Int[Array, ""]
    status: Int[Array, ""]

    @property
    def ok(self) -> Array:
        return self.status == FRAME_OK

    def to_frame(self, points: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
        """Camera-frame points (rows) → coordinates in frame n."""
        return (points - self.origin[..., None, :]) @ self.axes


def _sign_fix(v: Float[Array, "3"]) -> Float[Array, "3"]:
    return jnp.where(v[jnp.argmax(jnp.abs(v))] < 0, -v, v)


def plane_frame(cloud: Cloud) -> PlaneFrame:
    """The plane frame n of a cloud (the previous cloud of a pair).

    Pure and jittable. Problems are reported in `status`, never by NaN: with no valid points
    the origin is zero and the axes are the identity.
    """
    points = cloud.masked_points
    w = cloud.valid.astype(points.dtype)
    n = jnp.sum(w)
    origin = jnp.sum(points * w[:, None], axis=0) / jnp.maximum(n, 1.0)
    X = (points - origin[None]) * w[:, None]
    C = X.T @ X
    J = jnp.trace(C) * jnp.eye(3, dtype=C.dtype) - C
    evals, evecs = jnp.linalg.eigh(J)  # ascending
    evals, evecs = evals[::-1], evecs[:, ::-1]
    n1, n2 = _sign_fix(evecs[:, 0]), _sign_fix(evecs[:, 1])
    axes = jnp.stack([n1, n2, jnp.cross(n1, n2)], axis=1)

    spreads = jnp.linalg.eigvalsh(C)  # ascending, ≥ 0 up to round-off
    scale = jnp.maximum(spreads[2], jnp.finfo(C.dtype).tiny)
    flat = spreads[1] <= FLATNESS_TOL * scale  # collinear (a coplanar cloud has spreads[0] = 0 only)
    gaps = jnp.minimum(evals[0] - evals[1], evals[1] - evals[2])
    ambiguous = gaps <= AMBIGUITY_TOL * jnp.maximum(evals[0], jnp.finfo(C.dtype).tiny)
    status = jnp.where(
        n < MIN_POINTS,
        FRAME_TOO_FEW_POINTS,
        jnp.where(flat, FRAME_FLAT, jnp.where(ambiguous, FRAME_AMBIGUOUS, FRAME_OK)),
    )
    ok = status == FRAME_OK
    axes = jnp.where(ok | (n >= 3), axes, jnp.eye(3, dtype=C.dtype))
    return PlaneFrame(origin, axes, evals, n.astype(jnp.int32), status.astype(jnp.int32))
