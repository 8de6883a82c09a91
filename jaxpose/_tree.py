"""Leaf-wise helpers for pytrees of arrays (estimates, filter states, clouds) under jit."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool


def tree_select(condition, new, old):
    """`new` where `condition` holds, else `old`, leaf by leaf (pytrees of one structure)."""
    return jax.tree.map(lambda a, b: jnp.where(condition, a, b), new, old)


def tree_finite(tree) -> Bool[Array, ""]:
    """True when every element of every leaf of `tree` is finite."""
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]))
