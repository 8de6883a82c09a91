"""Point clouds: fixed-shape points with a validity mask, so that clouds jit and vmap."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Real


class Cloud(eqx.Module):
    """A point cloud in the camera frame c (metres).

    **Fields:**

    - `points`: `(N, 3)` coordinates; rows with `valid == False` are ignored everywhere
      (the simulator puts zeros there).
    - `valid`: `(N,)` boolean mask of the points that exist.

    The constructor does no checking so it can be used inside `jax.jit`; use
    [`Cloud.from_points`][] at the Python boundary.
    """

    points: Real[Array, "*batch N 3"]
    valid: Bool[Array, "*batch N"]

    @classmethod
    def from_points(cls, points, valid=None) -> Cloud:
        """A checked cloud from an `(N, 3)` array of camera-frame points in metres.

        `valid` (optional, `(N,)` booleans) marks the points that exist; invalid rows may
        hold anything, NaN included (they are zeroed). Raises ValueError on wrong shape or
        dtype and on non-finite valid points.
        """
        p = np.asarray(points)
        v = np.ones(p.shape[:1], bool) if valid is None else np.asarray(valid)
        _check_arrays(p, v, "points")
        p = np.where(v[:, None], p, 0.0)
        return cls(jnp.asarray(p, jnp.result_type(float)), jnp.asarray(v))

    def check(self, name: str = "cloud") -> None:
        """Raise a ValueError naming `name` unless points are `(N, 3)` reals, `valid` an `(N,)`
        boolean mask and every valid point finite (outside jit only)."""
        _check_arrays(np.asarray(self.points), np.asarray(self.valid), name)

    @property
    def masked_points(self) -> Float[Array, "*batch N 3"]:
        """`points` as floats with the invalid rows zeroed, so NaN or inf that a sensor left
        in missing rows can never leak into sums (works under jit)."""
        floating = jnp.issubdtype(self.points.dtype, jnp.floating)
        dtype = self.points.dtype if floating else jnp.result_type(float)
        return jnp.where(self.valid[..., None], self.points, 0).astype(dtype)

    def floating(self) -> Cloud:
        """This cloud with `points` as `masked_points` (invalid rows zeroed) in JAX's default
        float dtype (float64 with `jax_enable_x64`, else float32): what the Python boundary
        passes on, so that integer or float32 points reuse the program of the session's
        precision instead of compiling one of their own, and no NaN of an invalid row enters
        it. Under x64 a float32 cloud would otherwise meet the libraries' float64 constants
        (evosax's, optimistix's) inside loops that need one dtype, and fail to trace."""
        return Cloud(self.masked_points.astype(jnp.result_type(float)), self.valid)

    @property
    def num_valid(self) -> Array:
        """Number of valid points (an array, so it works under jit)."""
        return jnp.sum(self.valid)

    def packed(self, size: int) -> Cloud:
        """This single cloud with its valid points moved to the front of `size` rows (order
        kept, the rest zeroed and invalid), so that later stages touch `size` rows, not the
        whole sensor frame. Points beyond `size` are dropped: callers compare `num_valid`
        with `size` and report the overflow. Static shapes (works under jit and vmap)."""
        (keep,) = jnp.nonzero(self.valid, size=size, fill_value=0)
        live = jnp.arange(size) < self.num_valid
        return Cloud(jnp.where(live[:, None], self.masked_points[keep], 0), live)

    def compact(self) -> np.ndarray:
        """The valid points as a plain `(n, 3)` numpy array (outside jit only)."""
        return np.asarray(self.points)[np.asarray(self.valid)]


def _check_arrays(points: np.ndarray, valid: np.ndarray, name: str) -> None:
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: expected points of shape (N, 3), got {points.shape}.")
    if not (np.issubdtype(points.dtype, np.floating) or np.issubdtype(points.dtype, np.integer)):
        raise ValueError(f"{name}: expected real numbers, got dtype {points.dtype}.")
    if valid.shape != points.shape[:1] or valid.dtype != np.bool_:
        raise ValueError(
            f"{name}: expected a boolean mask of shape ({points.shape[0]},), got {valid.dtype} {valid.shape}."
        )
    if not np.all(np.isfinite(points[valid])):
        raise ValueError(f"{name}: valid points contain NaN or inf; mask them out (valid=False).")
