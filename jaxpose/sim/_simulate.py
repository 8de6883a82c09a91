"""The ToF lidar simulator: one ray per pixel, first visible hit, range gate, optional noise.

Pure and jittable; vmap it over poses and keys. Hits are computed in structure-of-arrays
form (separate x/y/z arrays of all rays), which XLA on CPU runs far faster than batched
3 × 3 matmuls. Boxes use the analytic slab method; meshes use Möller–Trumbore, brute force
over triangle chunks.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._checks import as_float_array, check_rotation, is_concrete
from .._cloud import Cloud
from .._rotations import rotate_components
from ._camera import Camera
from .targets import Boxes, Mesh, Target

_TRIANGLE_CHUNK = 64


def _safe_inverse(d):
    tiny = jnp.finfo(d.dtype).tiny ** 0.5
    return 1.0 / jnp.where(jnp.abs(d) < tiny, jnp.where(d < 0, -tiny, tiny), d)


def _box_ranges(boxes: Boxes, R, t, rays) -> Float[Array, " P"]:
    """Distance along each unit ray from O_c to its first box hit (inf where none)."""

    def one_box(center, half, Rb):
        M = (R @ Rb).T  # camera → box axes
        o = -(M @ (R @ center + t))  # camera origin in the box frame
        d = rotate_components(M, *rays)
        t_near, t_far = -jnp.inf, jnp.inf
        for k in range(3):
            inv = _safe_inverse(d[k])
            a, b = (-half[k] - o[k]) * inv, (half[k] - o[k]) * inv
            t_near = jnp.maximum(t_near, jnp.minimum(a, b))
            t_far = jnp.minimum(t_far, jnp.maximum(a, b))
        return jnp.where((t_far >= t_near) & (t_near > 0), t_near, jnp.inf)

    ranges = jax.vmap(one_box)(boxes.centers, boxes.half_sizes, boxes.rotations)
    return jnp.min(ranges, axis=0)


def _mesh_ranges(mesh: Mesh, R, t, rays) -> Float[Array, " P"]:
    """Distance along each unit ray to its first triangle hit (Möller–Trumbore, two-sided)."""
    tris = mesh.triangles @ R.T + t[None, None]  # (T, 3, 3) in the camera frame
    pad = (-tris.shape[0]) % _TRIANGLE_CHUNK
    tris = jnp.concatenate([tris, jnp.zeros((pad, 3, 3), tris.dtype)])  # degenerate: no hits
    dx, dy, dz = (r[None, :] for r in rays)

    def chunk(best, tri):
        v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        col = lambda a, k: a[:, k, None]  # noqa: E731
        # p = d × e2, det = e1 · p
        px = dy * col(e2, 2) - dz * col(e2, 1)
        py = dz * col(e2, 0) - dx * col(e2, 2)
        pz = dx * col(e2, 1) - dy * col(e2, 0)
        det = col(e1, 0) * px + col(e1, 1) * py + col(e1, 2) * pz
        ok = jnp.abs(det) > 1e-12
        inv = 1.0 / jnp.where(ok, det, 1.0)
        s = -v0  # ray origin O_c = 0
        u = (col(s, 0) * px + col(s, 1) * py + col(s, 2) * pz) * inv
        qx = s[:, 1] * e1[:, 2] - s[:, 2] * e1[:, 1]
        qy = s[:, 2] * e1[:, 0] - s[:, 0] * e1[:, 2]
        qz = s[:, 0] * e1[:, 1] - s[:, 1] * e1[:, 0]
        v = (dx * qx[:, None] + dy * qy[:, None] + dz * qz[:, None]) * inv
        dist = (e2[:, 0] * qx + e2[:, 1] * qy + e2[:, 2] * qz)[:, None] * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (dist > 0)
        return jnp.minimum(best, jnp.min(jnp.where(hit, dist, jnp.inf), axis=0)), None

    tris = tris.reshape(-1, _TRIANGLE_CHUNK, 3, 3)
    best, _ = jax.lax.scan(chunk, jnp.full(rays[0].shape, jnp.inf, rays[0].dtype), tris)
    return best


FLYING_EDGE = 0.05
"""A range step (metres) between 4-neighbouring pixels above which both lie on a depth edge."""


def _image(camera: Camera, x: Array) -> Array:
    return x.reshape(camera.height, camera.width, *x.shape[1:])


def _noise_sigma(camera: Camera, rng, hit, rays) -> Float[Array, " P"]:
    """Range noise σ of each pixel (metres): `camera.noise_sigma`, or the ToF model of
    [`jaxpose.Camera`][] when `noise_range_ref` > 0. The angle of incidence comes from the
    noise-free range image: the normal of the surface through the pixel's right and lower
    neighbours (left and upper at the image border or across a depth edge; head-on where
    neither pair is on the same surface)."""
    if isinstance(camera.noise_range_ref, int | float) and camera.noise_range_ref == 0:
        return jnp.full_like(rng, camera.noise_sigma)
    P = _image(camera, jnp.stack([r * rng for r in rays], -1))
    ok = _image(camera, hit)

    def step(axis):
        fwd, bwd = jnp.roll(P, -1, axis) - P, P - jnp.roll(P, 1, axis)
        fwd_ok = ok & jnp.roll(ok, -1, axis) & (jnp.linalg.norm(fwd, axis=-1) < FLYING_EDGE)
        bwd_ok = ok & jnp.roll(ok, 1, axis) & (jnp.linalg.norm(bwd, axis=-1) < FLYING_EDGE)
        return jnp.where(fwd_ok[..., None], fwd, bwd), fwd_ok | bwd_ok

    (du, u_ok), (dv, v_ok) = step(1), step(0)
    normal = jnp.cross(du, dv)
    size = jnp.linalg.norm(normal, axis=-1)
    ray = _image(camera, jnp.stack(rays, -1))
    cos = jnp.abs(jnp.sum(normal * ray, -1)) / jnp.where(size > 0, size, 1.0)
    cos = jnp.where(u_ok & v_ok & (size > 0), cos, 1.0).ravel()
    # Under jit the reference is traced: a reference of 0 must still mean a constant σ.
    ref = camera.noise_range_ref
    growth = (rng / jnp.where(ref > 0, ref, 1.0)) / jnp.sqrt(jnp.maximum(cos, 0.1))
    return camera.noise_sigma * jnp.where(ref > 0, growth, 1.0)


def _flying_pixels(camera: Camera, rng, hit, key) -> Float[Array, " P"]:
    """Mixed ranges at depth edges: with probability `camera.flying`, a pixel whose randomly
    chosen 4-neighbour is a hit more than `FLYING_EDGE` away in range takes a range uniformly
    between the two (a pixel that sees both surfaces)."""
    if isinstance(camera.flying, int | float) and camera.flying == 0:
        return rng
    k_side, k_mix, k_on = jax.random.split(key, 3)
    R, ok = _image(camera, rng), _image(camera, hit)
    shifts = ((0, 1), (0, -1), (1, 0), (-1, 0))
    side = jax.random.randint(k_side, R.shape, 0, 4)
    neighbour = jnp.stack([jnp.roll(R, s, (0, 1)) for s in shifts])
    neighbour_ok = jnp.stack([jnp.roll(ok, s, (0, 1)) for s in shifts])
    pick = lambda a: jnp.take_along_axis(a, side[None], 0)[0]  # noqa: E731
    other, other_ok = pick(neighbour), pick(neighbour_ok)
    edge = ok & other_ok & (jnp.abs(other - R) > FLYING_EDGE)
    mix = jax.random.uniform(k_mix, R.shape, R.dtype)
    on = edge & (jax.random.uniform(k_on, R.shape) < camera.flying)
    return jnp.where(on, R + mix * (other - R), R).ravel()


def _check_inputs(camera: Camera, target: Target, R, t, key) -> None:
    check_rotation(R)
    as_float_array(t, "t", (3,))
    if isinstance(target, Boxes):
        as_float_array(target.centers, "target.centers", (None, 3))
        if target.num_boxes == 0:
            raise ValueError("target is empty: it has no boxes.")
        if not bool(jnp.all(target.half_sizes > 0)):
            raise ValueError("target box sizes must all be positive (metres).")
    elif isinstance(target, Mesh):
        as_float_array(target.triangles, "target.triangles", (None, 3, 3))
        if target.triangles.shape[0] == 0:
            raise ValueError("target is empty: the mesh has no triangles.")
    else:
        raise ValueError(f"target must be jaxpose.targets.Boxes or Mesh, got {type(target).__name__}.")
    if not 0 <= float(camera.range_min) < float(camera.range_max):
        raise ValueError("camera range gate needs 0 ≤ range_min < range_max (metres).")
    if float(camera.noise_sigma) < 0 or not 0 <= float(camera.dropout) < 1:
        raise ValueError("camera noise_sigma must be ≥ 0 and dropout in [0, 1).")
    if float(camera.noise_range_ref) < 0 or not 0 <= float(camera.flying) <= 1:
        raise ValueError("camera noise_range_ref must be ≥ 0 (metres) and flying in [0, 1].")
    noisy = float(camera.noise_sigma) > 0 or float(camera.dropout) > 0 or float(camera.flying) > 0
    if key is None and noisy:
        raise ValueError("the camera has noise, dropout or flying pixels: pass a PRNG key to simulate(…, key=…).")


def simulate(
    camera: Camera,
    target: Target,
    R: ArrayLike,
    t: ArrayLike,
    key: PRNGKeyArray | None = None,
) -> Cloud:
    """Simulate one ToF frame of a target at pose (R, t).

    **Arguments:**

    - `camera`: the [`jaxpose.Camera`][].
    - `target`: [`jaxpose.targets.Boxes`][] or [`jaxpose.targets.Mesh`][], in frame t.
    - `R`: target attitude G^c_t (target → camera), a rotation matrix.
    - `t`: position of O_t in the camera frame, metres.
    - `key`: PRNG key for range noise and dropout. Without a key the frame is ideal
      (noise-free); a camera with noise or dropout then raises at the Python boundary.

    **Returns:**

    A [`jaxpose.Cloud`][] with `points` of shape `(H·W, 3)` in the camera frame (index
    v · W + u) and `valid` true where the first visible hit lies inside the range gate and
    the pixel did not drop out. The gate acts on the measured (noisy) range. Invalid points
    are zero.
    """
    if is_concrete(camera, target, R, t):
        _check_inputs(camera, target, R, t, key)
    R, t = jnp.asarray(R), jnp.asarray(t)
    rays = tuple(camera.ray_directions().astype(R.dtype))
    if isinstance(target, Boxes):
        rng = _box_ranges(target, R, t, rays)
    else:
        rng = _mesh_ranges(target, R, t, rays)
    hit = jnp.isfinite(rng)
    rng = jnp.where(hit, rng, 0.0)
    valid = hit
    if key is not None:
        k_noise, k_drop = jax.random.split(key)
        k_fly = jax.random.fold_in(key, 2)
        sigma = _noise_sigma(camera, rng, hit, rays)
        rng = _flying_pixels(camera, rng, hit, k_fly)
        rng = rng + sigma * jax.random.normal(k_noise, rng.shape, rng.dtype)
        valid = valid & (jax.random.uniform(k_drop, rng.shape) >= camera.dropout)
    valid = valid & (rng >= camera.range_min) & (rng <= camera.range_max)
    rng = jnp.where(valid, rng, 0.0)
    return Cloud(jnp.stack([r * rng for r in rays], axis=-1), valid)
