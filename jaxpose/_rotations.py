"""The paper's Tait–Bryan rotation G(θ, φ, ψ) = R_y(θ) · R_x(φ) · R_z(ψ) and its inverse.

All angles are in **radians**. `rotation` builds the transition matrix of a frame turned
by pitch θ about y, then roll φ about the new x, then yaw ψ about the newest z (intrinsic
y–x′–z″); its columns are the turned frame's axes written in the original frame.
This is exactly the matrix printed in the paper (METHOD.md §4, DECISIONS.md "Frames").
"""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import jaxlie
import numpy as np
from jaxtyping import Array, ArrayLike, Float


def rotation(theta: ArrayLike, phi: ArrayLike, psi: ArrayLike) -> Float[Array, "*batch 3 3"]:
    """The paper's rotation matrix G(θ, φ, ψ) = R_y(θ) R_x(φ) R_z(ψ).

    **Arguments:**

    - `theta`: pitch θ about y, radians.
    - `phi`: roll φ about x, radians.
    - `psi`: yaw ψ about z, radians.

    Arguments broadcast against each other.

    **Returns:**

    The `(..., 3, 3)` rotation matrix. For a displacement it is G^n_ν: it maps components in
    the moved frame ν to components in the plane frame n, `v_n = G @ v_ν`.
    """
    theta, phi, psi = jnp.broadcast_arrays(*(jnp.asarray(a) for a in (theta, phi, psi)))
    if not jnp.issubdtype(theta.dtype, jnp.floating):
        theta, phi, psi = (a.astype(jnp.result_type(float)) for a in (theta, phi, psi))
    st, ct = jnp.sin(theta), jnp.cos(theta)
    sf, cf = jnp.sin(phi), jnp.cos(phi)
    ss, cs = jnp.sin(psi), jnp.cos(psi)
    rows = (
        (st * sf * ss + ct * cs, st * sf * cs - ct * ss, st * cf),
        (cf * ss, cf * cs, -sf),
        (ct * sf * ss - st * cs, ct * sf * cs + st * ss, ct * cf),
    )
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def angles(G: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 3"]:
    """Inverse of [`rotation`][]: the angles (θ, φ, ψ) in radians of a rotation matrix.

    θ = atan2(G[0,2], G[2,2]), φ = −asin(G[1,2]), ψ = atan2(G[1,0], G[1,1]), with
    θ, ψ ∈ (−π, π] and φ ∈ [−π/2, π/2].

    **Gimbal lock.** At φ = ±π/2 (G[1,2] = ∓1) only θ ∓ ψ is defined. There (when cos φ,
    computed as hypot(G[0,2], G[2,2]), is below 1000 machine epsilons) the function returns
    ψ = 0 and puts the whole defined combination into θ = atan2(−G[1,2]·G[0,1], G[0,0]), so
    `rotation(*angles(G))` still reproduces G. Near the lock the angles are ill-conditioned:
    compare rotations through their matrices ([`rotation_angle`][]) there. G[1,2] is clipped
    to [−1, 1] so round-off never gives NaN.

    **Returns:**

    `(..., 3)` array (θ, φ, ψ), radians.
    """
    G = jnp.asarray(G)
    if not jnp.issubdtype(G.dtype, jnp.floating):
        G = G.astype(jnp.result_type(float))
    cos_phi = jnp.hypot(G[..., 0, 2], G[..., 2, 2])
    locked = cos_phi < 1e3 * jnp.finfo(G.dtype).eps
    theta = jnp.where(
        locked,
        jnp.arctan2(-G[..., 1, 2] * G[..., 0, 1], G[..., 0, 0]),
        jnp.arctan2(G[..., 0, 2], G[..., 2, 2]),
    )
    phi = -jnp.arcsin(jnp.clip(G[..., 1, 2], -1.0, 1.0))
    psi = jnp.where(locked, 0.0, jnp.arctan2(G[..., 1, 0], G[..., 1, 1]))
    return jnp.stack([theta, phi, psi], axis=-1)


def rotation_angle(A: Float[ArrayLike, "*batch 3 3"], B: Float[ArrayLike, "*batch 3 3"]):
    """Angle in radians of the rotation A Bᵀ (the geodesic distance between A and B).

    Uses the atan2 form, accurate for tiny and near-π angles alike.
    """
    A, B = jnp.asarray(A), jnp.asarray(B)
    D = A @ jnp.swapaxes(B, -1, -2)
    cos_part = jnp.trace(D, axis1=-2, axis2=-1) - 1.0
    axis = jnp.stack(
        [D[..., 2, 1] - D[..., 1, 2], D[..., 0, 2] - D[..., 2, 0], D[..., 1, 0] - D[..., 0, 1]],
        axis=-1,
    )
    return jnp.arctan2(jnp.linalg.norm(axis, axis=-1), cos_part)


def rotate_components(M: Float[Array, "3 3"], x: Array, y: Array, z: Array) -> tuple[Array, Array, Array]:
    """M (x, y, z)ᵀ for points held as three component arrays (structure of arrays).

    Nine multiply-adds per point instead of a `(N, 3) @ (3, 3)` product: under `vmap` over
    candidate poses this is about ten times faster on CPU (see docs/performance.md).
    """
    return (
        M[0, 0] * x + M[0, 1] * y + M[0, 2] * z,
        M[1, 0] * x + M[1, 1] * y + M[1, 2] * z,
        M[2, 0] * x + M[2, 1] * y + M[2, 2] * z,
    )


def into_moved_frame(p: Float[Array, "6"], x: Array, y: Array, z: Array) -> tuple[Array, Array, Array]:
    """Points of plane frame n, as component arrays, written in the moved frame ν of the
    displacement p = (θ, φ, ψ, x, y, z): q = G(θ, φ, ψ)ᵀ (b − (x, y, z)) (METHOD.md §5).
    Radians and metres."""
    G = rotation(p[0], p[1], p[2])
    return rotate_components(G.T, x - p[3], y - p[4], z - p[5])


SUPER_FIBONACCI_PSI = 1.533751168755204288118041
"""ψ of the super-Fibonacci spiral (Alexa, "Super-Fibonacci Spirals", CVPR 2022): the real root
of ψ⁴ = ψ + 4, paired with φ = √2."""


def super_fibonacci(n: int) -> Float[Array, "n 3 3"]:
    """`n` rotations spread evenly over the whole rotation group: Alexa's super-Fibonacci
    spiral of unit quaternions (CVPR 2022), as matrices (jaxlie). Deterministic; for n = 8192
    every rotation lies within about 11° of one of them (`tests/test_capture.py` checks it on
    2000 random rotations)."""
    s = jnp.arange(n) + 0.5
    r, R = jnp.sqrt(s / n), jnp.sqrt(1 - s / n)
    alpha = 2 * jnp.pi * s / jnp.sqrt(2.0)
    beta = 2 * jnp.pi * s / SUPER_FIBONACCI_PSI
    wxyz = jnp.stack([R * jnp.cos(beta), r * jnp.sin(alpha), r * jnp.cos(alpha), R * jnp.sin(beta)], axis=-1)
    return jaxlie.SO3(wxyz).as_matrix()


def signed_permutations() -> Float[Array, "24 3 3"]:
    """The 24 proper rotations that map the coordinate axes onto themselves (the rotation group
    of the cube): every permutation of the axes with every choice of signs whose determinant
    is +1. They align two principal frames whatever the order and signs of their axes."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[list(range(3)), list(perm)] = signs
            if np.linalg.det(M) > 0:
                out.append(M)
    return jnp.asarray(np.stack(out))
