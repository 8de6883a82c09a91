"""Point clouds: fixed-shape points with a validity mask, so that clouds jit and vmap."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._checks import as_float_array


class Cloud(eqx.Module):
    """A point cloud in the camera frame c (metres).

    **Fields:**

    - `points`: `(N, 3)` coordinates; rows with `valid == False` are ignored everywhere
      (the simulator puts zeros there).
    - `valid`: `(N,)` boolean mask of the points that exist.

    The constructor does no checking so it can be used inside `jax.jit`; use
    [`Cloud.from_points`][] at the Python boundary.
    """

    points: Float[Array, "N 3"]
    valid: Bool[Array, " N"]

    @classmethod
    def from_points(cls, points, valid=None) -> Cloud:
        """A checked cloud from an `(N, 3)` array of camera-frame points in metres.

        `valid` (optional, `(N,)` booleans) marks the points that exist; invalid rows may
        hold anything, NaN included (they are zeroed). Raises ValueError on wrong shape or
        dtype and on non-finite valid points.
        """
        p = np.asarray(points)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points: expected shape (N, 3), got {p.shape}.")
        if not (np.issubdtype(p.dtype, np.floating) or np.issubdtype(p.dtype, np.integer)):
            raise ValueError(f"points: expected real numbers, got dtype {p.dtype}.")
        if valid is None:
            v = np.ones(p.shape[0], bool)
        else:
            v = np.asarray(valid)
            if v.shape != (p.shape[0],) or v.dtype != np.bool_:
                raise ValueError(f"valid: expected a boolean mask of shape ({p.shape[0]},), got {v.dtype} {v.shape}.")
        p = np.where(v[:, None], p, 0.0)
        as_float_array(p, "points")  # finite check on the valid rows
        return cls(jnp.asarray(p, jnp.result_type(float)), jnp.asarray(v))

    @property
    def num_valid(self) -> Array:
        """Number of valid points (an array, so it works under jit)."""
        return jnp.sum(self.valid)

    def compact(self) -> np.ndarray:
        """The valid points as a plain `(n, 3)` numpy array (outside jit only)."""
        return np.asarray(self.points)[np.asarray(self.valid)]
