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
from ._fine import FitMatches, SurfaceProblem, fine_least_squares
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


def covariance_factor(config: Config, sigma: Float[ArrayLike, ""]) -> Float[Array, ""]:
    """The factor k(σ̂) = `FineStage.covariance_scale` · (1 + σ̂ / `FineStage.covariance_noise`)
    that turns the least-squares covariance σ̂² (JᵀJ)⁻¹ of a fit with residual scale `sigma`
    (σ̂, metres) into the predicted one. The fit's errors grow faster with the range noise than
    σ̂² (JᵀJ)⁻¹ does (the planes fitted to noisy neighbourhoods tilt, and neighbouring
    residuals share the tilt), so the factor grows with σ̂; `covariance_noise` = inf keeps it
    constant."""
    stage = config.fine
    return stage.covariance_scale * (1 + jnp.asarray(sigma) / stage.covariance_noise)


def motion_uncertainty(
    problem: SurfaceProblem, config: Config, p: Float[Array, "6"], matches: FitMatches | None = None
) -> tuple[Float[Array, "6 6"], Float[Array, ""]]:
    """[`motion_covariance`][] and the residual scale σ̂ (metres) it was scaled with.
    `matches`: `jaxpose._fine.fit_matches` at p, where the caller has them."""
    R_hat, _ = motion_from_displacement(problem.frame.origin, problem.frame.axes, p)

    def motion(q):
        R, t = motion_from_displacement(problem.frame.origin, problem.frame.axes, q)
        return jnp.concatenate([jaxlie.SO3.from_matrix(R @ R_hat.T).log(), t])

    J = jax.jacfwd(motion)(p)
    sigma, unit = fine_least_squares(problem, config, p, matches)
    cov = covariance_factor(config, sigma) * sigma**2 * unit
    out = J @ cov @ J.T
    return (out + out.T) / 2, sigma


def motion_covariance(problem: SurfaceProblem, config: Config, p: Float[Array, "6"]) -> Float[Array, "6 6"]:
    """Covariance of the camera-frame motion (R, t) that a fine-stage result p (frame n)
    measures: J Σ_p Jᵀ, with Σ_p = k(σ̂) σ̂² (JᵀJ)⁻¹ the fine stage's least-squares covariance
    ([`jaxpose._fine.fine_least_squares`][]) times [`covariance_factor`][] (from
    `FineStage.covariance_scale` and `FineStage.covariance_noise`) and J the Jacobian of
    p ↦ (log(R(p) R(p̂)ᵀ), t(p)) at p̂. The rotation as a left rotation vector in radians
    (frame c), then the translation in metres."""
    return motion_uncertainty(problem, config, p)[0]


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
    "covariance_factor",
    "curvature",
    "motion_covariance",
    "motion_uncertainty",
    "nees",
    "rotation_std",
]
