"""Test scenarios: the paper's four cloud pairs and random pairs for capture and sweep studies.

A [`Pair`][] holds two simulated clouds and the target poses that made them (camera frame c,
metres, radians), so any estimate can be scored against the truth. Used by the reproduction,
`sweep`, `compare` and the experiment scripts, so they all mean the same pairs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jaxlie
from jaxtyping import Array, Float, PRNGKeyArray

from .._cloud import Cloud
from .._poses import relative_motion
from .._rotations import rotation
from . import targets
from ._camera import Camera
from ._simulate import simulate

PAPER_POSES = {"previous": (23.5, 23.5, 1.0), "variant 1": (24.5, 24.5, 2.0), "variant 2": (33.5, 33.5, 11.0)}
"""Target attitudes (θt, φt, ψt) in degrees of the paper's test (METHOD.md §11.4)."""
PAPER_T = (0.0, 0.0, 5.5)
"""Position of the target origin O_t in frame c, metres (all three poses)."""


class Pair(NamedTuple):
    """Two clouds of one target and its poses (R: target → camera attitude, t: O_t in frame c, m)."""

    label: str
    prev: Cloud
    curr: Cloud
    R1: Float[Array, "3 3"]
    t1: Float[Array, "3"]
    R2: Float[Array, "3 3"]
    t2: Float[Array, "3"]

    @property
    def motion(self) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
        """The true camera-frame motion x ↦ R x + t from the previous to the current cloud."""
        return relative_motion(self.R1, self.t1, self.R2, self.t2)


def paper_pose(name: str) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """Attitude and position of the paper's pose `name` ("previous", "variant 1", "variant 2")."""
    return rotation(*(math.radians(a) for a in PAPER_POSES[name])), jnp.asarray(PAPER_T)


def paper_pair(shape: str, variant: str, camera: Camera | None = None) -> Pair:
    """The paper's noise-free pair: `shape` "N1" or "N5", previous pose → `variant`."""
    camera = Camera.camcube2() if camera is None else camera
    target = getattr(targets, shape.lower())()
    (R1, t1), (R2, t2) = paper_pose("previous"), paper_pose(variant)
    prev, curr = simulate(camera, target, R1, t1), simulate(camera, target, R2, t2)
    return Pair(f"{shape} {variant}", prev, curr, R1, t1, R2, t2)


def paper_pairs(camera: Camera | None = None) -> list[Pair]:
    """N1 and N5, variants 1 and 2, in the order of the paper's tables."""
    return [paper_pair(s, v, camera) for v in ("variant 1", "variant 2") for s in ("N1", "N5")]


def rotated_pair(
    key: PRNGKeyArray,
    angle: float,
    *,
    attitude: Float[Array, "3 3"] | None = None,
    distance: float = 5.5,
    camera: Camera | None = None,
    target=None,
    label: str = "",
) -> Pair:
    """A target rotated by `angle` (radians) about a random axis through its origin O_t.

    **Arguments:**

    - `key`: PRNG key for the axis (and the attitude when `attitude` is None, and the
      camera's noise and dropout).
    - `attitude`: previous attitude R1; None draws a uniformly random one.
    - `distance`: O_t at (0, 0, distance) in frame c, metres.
    - `camera`, `target`: default CamCube 2.0 and N5.

    **Returns:** a [`Pair`][] with R2 = exp(angle · axis) R1, t2 = t1.
    """
    camera = Camera.camcube2() if camera is None else camera
    target = targets.n5() if target is None else target
    k_att, k_axis, k_prev, k_curr = jax.random.split(key, 4)
    R1 = jaxlie.SO3.sample_uniform(k_att).as_matrix() if attitude is None else jnp.asarray(attitude)
    axis = jax.random.normal(k_axis, (3,))
    R2 = jaxlie.SO3.exp(axis / jnp.linalg.norm(axis) * angle).as_matrix() @ R1
    t = jnp.asarray([0.0, 0.0, distance])
    noisy = float(camera.noise_sigma) > 0 or float(camera.dropout) > 0
    prev = simulate(camera, target, R1, t, k_prev if noisy else None)
    curr = simulate(camera, target, R2, t, k_curr if noisy else None)
    return Pair(label or f"{math.degrees(angle):.1f}°", prev, curr, R1, t, R2, t)


def capture_pair(i: int, seed: int = 0, low_deg: float = 5.0, high_deg: float = 45.0) -> Pair:
    """Pair i of the capture set of issue 4: N5 at 5.5 m, uniformly random attitude, rotated
    by an angle uniform in [`low_deg`, `high_deg`] degrees about a random axis; noise-free.
    It uses key (seed, i), so the pair is the same in every run and for every method."""
    k_angle, k_pair = jax.random.split(jax.random.fold_in(jax.random.key(seed), i))
    angle = math.radians(float(jax.random.uniform(k_angle, minval=low_deg, maxval=high_deg)))
    return rotated_pair(k_pair, angle, label=f"capture {i}")


def capture_pairs(count: int, seed: int = 0, low_deg: float = 5.0, high_deg: float = 45.0) -> list[Pair]:
    """Pairs 0 … count − 1 of the capture set ([`capture_pair`][])."""
    return [capture_pair(i, seed, low_deg, high_deg) for i in range(count)]


__all__ = [
    "PAPER_POSES",
    "PAPER_T",
    "Pair",
    "capture_pair",
    "capture_pairs",
    "paper_pair",
    "paper_pairs",
    "paper_pose",
    "rotated_pair",
]
