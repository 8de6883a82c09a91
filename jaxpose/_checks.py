"""Validation helpers for the Python boundary.

Inside `jax.jit` the values are tracers and cannot be inspected; these helpers then do
nothing and the jitted code reports problems through status fields instead.
"""

from __future__ import annotations

import jax
import numpy as np


def is_concrete(*xs) -> bool:
    """True when no argument is a JAX tracer, i.e. values can be inspected and errors raised."""
    return not any(isinstance(leaf, jax.core.Tracer) for x in xs for leaf in jax.tree.leaves(x))


def as_float_array(x, name: str, shape: tuple[int | None, ...] | None = None) -> np.ndarray:
    """`x` as a finite real numpy array of the given shape (None = any length), or a ValueError."""
    try:
        a = np.asarray(x)
    except Exception as err:  # pragma: no cover - numpy's own message is clear enough
        raise ValueError(f"{name}: cannot be read as an array ({err}).") from err
    if a.dtype == object or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise ValueError(f"{name}: expected real numbers, got dtype {a.dtype}.")
    if shape is not None:
        ok = a.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, a.shape, strict=True))
        if not ok:
            want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name}: expected shape {want}, got {a.shape}.")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or infinite values; remove or mask them first.")
    return a


def check_rotation(R, name: str = "R", tol: float = 1e-4) -> None:
    """A ValueError unless R is a finite proper rotation matrix (RᵀR = I, det R = +1)."""
    a = as_float_array(R, name, (3, 3)).astype(np.float64)
    if not np.allclose(a.T @ a, np.eye(3), atol=tol) or np.linalg.det(a) < 0:
        raise ValueError(f"{name}: not a rotation matrix (needs RᵀR = I and det R = +1).")
