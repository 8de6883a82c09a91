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
from jaxtyping import Array, ArrayLike, Float

from ._objective import soft_score
from ._poses import PARAMETER_SCALE
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


def nees(error: Float[ArrayLike, "6"], sigma: Float[ArrayLike, "6 6"]) -> Float[Array, ""]:
    """Normalised estimation error squared eᵀ Σ⁻¹ e (χ² with 6 degrees of freedom if Σ is right)."""
    return error @ jnp.linalg.solve(sigma, error)


__all__ = ["covariance", "curvature", "nees"]
