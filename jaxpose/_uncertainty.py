"""Measurement covariance of a displacement from the soft objective's curvature (issue 7).

At the optimum p̂ the soft objective f is locally quadratic, f(p) ≈ f(p̂) − ½ (p − p̂)ᵀ H (p − p̂),
and the covariance of p̂ is taken as Σ = s² H⁻¹. f is not a log-likelihood, so the scale s²
is not known a priori: it must be calibrated on a Monte Carlo set (so that the mean NEES is
the dimension, 6) and checked on an independent one (`experiments/nees.py`). Units of p:
radians and metres, frame n.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, ArrayLike, Float

from ._config import COVARIANCE_SCALE, Config
from ._fine import SurfaceProblem, fine_covariance
from ._objective import soft_score
from ._poses import PARAMETER_SCALE, motion_from_displacement
from ._problem import Problem


def curvature(p: Float[Array, "6"], problem: Problem) -> Float[Array, "6 6"]:
    """Hessian of −f (the soft objective) at p, in the units of p (radians, metres).

    Differentiated in the local stage's units (1°, 1 cm) for conditioning, then converted.
    """
    scale = jnp.asarray(PARAMETER_SCALE, problem.d.dtype)
    H = jax.hessian(lambda y: -soft_score(y * scale, problem))(p / scale)
    return H / scale[:, None] / scale[None, :]


def covariance(p: Float[Array, "6"], problem: Problem, scale2: float) -> Float[Array, "6 6"]:
    """Σ = scale2 · H⁻¹ at p (radians and metres squared); symmetrised. Pure and jittable.
    Where H is not positive definite the result has non-finite or negative entries on its
    diagonal: check it before use."""
    H = curvature(p, problem)
    sigma = scale2 * jnp.linalg.inv(H)
    return (sigma + sigma.T) / 2


def motion_covariance(problem: SurfaceProblem, config: Config, p: Float[Array, "6"]) -> Float[Array, "6 6"]:
    """Covariance of the camera-frame motion (R, t) that a fine-stage result p (frame n)
    measures: J Σ_p Jᵀ, with Σ_p the fine stage's least-squares covariance scaled by
    `FineStage.covariance_scale` (default `COVARIANCE_SCALE`) and J the Jacobian of
    p ↦ (log(R(p) R(p̂)ᵀ), t(p)) at p̂. The rotation as a left rotation vector in radians
    (frame c), then the translation in metres."""
    R_hat, _ = motion_from_displacement(problem.frame.origin, problem.frame.axes, p)

    def motion(q):
        R, t = motion_from_displacement(problem.frame.origin, problem.frame.axes, q)
        return jnp.concatenate([jaxlie.SO3.from_matrix(R @ R_hat.T).log(), t])

    J = jax.jacfwd(motion)(p)
    cov = config.fine.covariance_scale * fine_covariance(problem, config, p)
    out = J @ cov @ J.T
    return (out + out.T) / 2


def rotation_std(cov: Float[Array, "6 6"]) -> Float[Array, ""]:
    """The largest standard deviation of the rotation (radians) of a motion covariance (6, 6)
    from [`motion_covariance`][]: the square root of its rotation block's largest eigenvalue;
    NaN where that block is not a covariance (non-finite)."""
    block = cov[:3, :3]
    finite = jnp.all(jnp.isfinite(block))
    largest = jnp.linalg.eigvalsh(jnp.where(finite, block, jnp.eye(3)))[-1]
    return jnp.where(finite, jnp.sqrt(jnp.maximum(largest, 0.0)), jnp.nan)


def nees(error: Float[ArrayLike, "6"], sigma: Float[ArrayLike, "6 6"]) -> Float[Array, ""]:
    """Normalised estimation error squared eᵀ Σ⁻¹ e (χ² with 6 degrees of freedom if Σ is right)."""
    return error @ jnp.linalg.solve(sigma, error)


__all__ = [
    "COVARIANCE_SCALE",
    "covariance",
    "curvature",
    "motion_covariance",
    "nees",
    "rotation_std",
]
