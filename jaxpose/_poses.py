"""Rigid poses and the displacement parameters p = (θ, φ, ψ, x, y, z) of the paper.

Conventions (DECISIONS.md "Frames and angles"):

- A pose (R, t) maps target coordinates to camera coordinates, `x_c = R x_t + t`; R is the
  paper's G^c_t. Lengths in metres, angles in radians.
- A displacement p describes frame ν relative to the plane frame n: G^n_ν = G(θ, φ, ψ) and
  O_ν = O_n + G^c_n (x, y, z), i.e. (x, y, z) is the shift of the origin written in frame n.
- A target motion (R_rel, t_rel) in the camera frame maps a point of the target at the
  previous instant to the same point at the current one: `x' = R_rel x + t_rel`.

Pose algebra beyond this (composition, inversion) is jaxlie's SE(3); this module only adds
the paper's frame bookkeeping and the units of p.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._rotations import angles, rotation

PARAMETER_SCALE = (math.pi / 180.0,) * 3 + (0.01,) * 3
"""The unit of each displacement parameter in the local and fine solvers' coordinates and in
their tolerances: 1° for θ, φ, ψ and 1 cm for x, y, z (radians and metres per unit)."""


def relative_motion(R1, t1, R2, t2) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """Camera-frame motion of a target that moves from pose (R1, t1) to (R2, t2).

    Returns (R_rel, t_rel) with R_rel = R2 R1ᵀ and t_rel = t2 − R_rel t1, so that a target
    point seen at x in the previous cloud is seen at R_rel x + t_rel in the current one.
    """
    R1, R2 = jnp.asarray(R1), jnp.asarray(R2)
    R_rel = R2 @ R1.T
    return R_rel, jnp.asarray(t2) - R_rel @ jnp.asarray(t1)


def displacement_from_motion(
    origin: Float[ArrayLike, "3"], axes: Float[ArrayLike, "3 3"], R_rel, t_rel
) -> Float[Array, "6"]:
    """Displacement p in frame n of a camera-frame target motion (R_rel, t_rel).

    **Arguments:**

    - `origin`: O_n in the camera frame, metres.
    - `axes`: G^c_n, columns n1 n2 n3 in the camera frame.
    - `R_rel`, `t_rel`: the target motion in the camera frame.

    **Returns:**

    p = (θ, φ, ψ, x, y, z): G(θ, φ, ψ) = G^c_nᵀ R_rel G^c_n (radians) and
    (x, y, z) = G^c_nᵀ (R_rel O_n + t_rel − O_n) in frame n (metres).
    """
    O, A, R_rel = jnp.asarray(origin), jnp.asarray(axes), jnp.asarray(R_rel)
    G = A.T @ R_rel @ A
    xyz = A.T @ (R_rel @ O + jnp.asarray(t_rel) - O)
    return jnp.concatenate([angles(G), xyz])


def motion_from_displacement(
    origin: Float[ArrayLike, "3"], axes: Float[ArrayLike, "3 3"], p: Float[ArrayLike, "6"]
) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """Inverse of [`displacement_from_motion`][]: the camera-frame motion (R_rel, t_rel) of p.

    R_rel = G^c_n G(θ, φ, ψ) G^c_nᵀ and t_rel = O_n + G^c_n (x, y, z) − R_rel O_n.
    """
    O, A, p = jnp.asarray(origin), jnp.asarray(axes), jnp.asarray(p)
    R_rel = A @ rotation(p[0], p[1], p[2]) @ A.T
    return R_rel, O + A @ p[3:] - R_rel @ O


def preceded_by_turn(p: Float[Array, "6"], S: Float[Array, "3 3"], centre: Float[Array, "3"]) -> Float[Array, "6"]:
    """The displacement p (frame n) preceded by a turn S (3×3) of the body about its point
    `centre` (frame n, metres): the body turns by S about c, then moves by p, so that
    G' = G S and x' = x + G (c − S c)."""
    G = rotation(*p[:3])
    return jnp.concatenate([angles(G @ S), p[3:] + G @ (centre - S @ centre)]).astype(p.dtype)


def true_displacement(frame, R1, t1, R2, t2) -> Float[Array, "6"]:
    """Ground-truth displacement p in the plane frame `frame` for a target moving (R1, t1) → (R2, t2).

    **Arguments:**

    - `frame`: a [`jaxpose.PlaneFrame`][] (or anything with `.origin` and `.axes`).
    - `R1`, `t1`: target pose in the camera frame at the previous instant (G^c_t, t_ct, metres).
    - `R2`, `t2`: the same at the current instant.

    **Returns:**

    p = (θ, φ, ψ, x, y, z), radians and metres, frame n (DECISIONS.md "Ground truth").
    """
    R_rel, t_rel = relative_motion(R1, t1, R2, t2)
    return displacement_from_motion(frame.origin, frame.axes, R_rel, t_rel)
