"""Procedural triangle meshes for the realistic targets (numpy, target frame t, metres).

Each function returns a `(T, 3, 3)` triangle soup; [`jaxpose.targets`][] joins them into
[`jaxpose.targets.Mesh`][] targets. The simulator's ray caster is two-sided, so open surfaces
(a nozzle, a dish, a torn panel) need no back faces.
"""

from __future__ import annotations

import numpy as np


def _axis_frame(axis: str) -> np.ndarray:
    """Columns: the two directions across `axis` and `axis` itself ("x", "y" or "z")."""
    k = "xyz".index(axis)
    return np.eye(3)[:, [(k + 1) % 3, (k + 2) % 3, k]]


def _place(tris: np.ndarray, axis: str, centre) -> np.ndarray:
    """Triangles built along z, turned so that z lies along `axis`, moved to `centre`."""
    return tris @ _axis_frame(axis).T + np.asarray(centre, float)


def _ring(radius: float, z: float, segments: int) -> np.ndarray:
    angle = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    return np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(segments, z)], 1)


def _band(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """The quad strip between two rings of equal size, as triangles."""
    nxt = np.roll(np.arange(len(lower)), -1)
    a, b, c, d = lower, lower[nxt], upper[nxt], upper
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _fan(ring: np.ndarray, centre: np.ndarray) -> np.ndarray:
    nxt = np.roll(np.arange(len(ring)), -1)
    return np.stack([np.broadcast_to(centre, ring.shape), ring, ring[nxt]], 1)


def frustum(r0: float, r1: float, length: float, axis="z", centre=(0, 0, 0), segments=24, caps=True) -> np.ndarray:
    """A truncated cone (a cylinder when r0 = r1) of radii r0 at −length/2 and r1 at +length/2
    along `axis`, closed by discs when `caps`."""
    lower, upper = _ring(r0, -length / 2, segments), _ring(r1, length / 2, segments)
    parts = [_band(lower, upper)]
    if caps:
        parts += [_fan(lower, np.array([0, 0, -length / 2])), _fan(upper, np.array([0, 0, length / 2]))]
    return _place(np.concatenate(parts), axis, centre)


def dish(radius: float, depth: float, axis="z", centre=(0, 0, 0), segments=24, rings=4) -> np.ndarray:
    """An open paraboloid z = depth·(ρ/radius)², its vertex at `centre`, opening along +axis."""
    rho = np.linspace(0.0, radius, rings + 1)[1:]
    circles = [_ring(r, depth * (r / radius) ** 2, segments) for r in rho]
    parts = [_fan(circles[0], np.zeros(3))] + [_band(a, b) for a, b in zip(circles, circles[1:], strict=False)]
    return _place(np.concatenate(parts), axis, centre)


def box(size, centre=(0, 0, 0)) -> np.ndarray:
    """An axis-aligned box of full edge lengths `size`, 12 triangles."""
    corners = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)])
    corners = corners * np.asarray(size, float) + np.asarray(centre, float)
    faces = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1]]
    faces += [[2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return corners[np.asarray(faces)]


def torn_panel(width: float, height: float, bend: float, seed: int = 0, segments: int = 40) -> np.ndarray:
    """A flat panel with a jagged, torn outline, bent by `bend` radians along a line across it.

    The outline is ρ(φ) = ellipse(width, height) · (1 + jitter(φ)) with a deterministic jitter
    from `seed`; the panel is a fan of two rings, and the part with x > width/8 is folded
    about the line x = width/8 (a crumple), which makes it irregular but rigid."""
    rng = np.random.default_rng(seed)
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    jitter = 1.0 + 0.18 * rng.uniform(-1, 1, segments) + 0.08 * np.sin(3 * phi + rng.uniform(0, 6))
    outer = np.stack([width / 2 * np.cos(phi) * jitter, height / 2 * np.sin(phi) * jitter, np.zeros(segments)], 1)
    inner = 0.5 * outer
    tris = np.concatenate([_fan(inner, np.zeros(3)), _band(inner, outer)])
    hinge = width / 8
    x = tris[..., 0] - hinge
    folded = x > 0
    c, s = np.cos(bend), np.sin(bend)
    tris = tris.copy()
    tris[..., 0] = np.where(folded, hinge + c * x, tris[..., 0])
    tris[..., 2] = np.where(folded, s * x, tris[..., 2])
    return tris


def rock(axes=(1.6, 1.1, 0.8), seed: int = 3, subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """An irregular, rock-like closed mesh (vertices, faces): an icosphere with smooth random
    radial bumps, scaled to the full extents `axes`. Used to write the packaged mesh file that
    the benchmark loads back through [`jaxpose.targets.Mesh.load`][]."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = np.asarray(sphere.vertices, float)
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(6, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    bumps = sum(a * np.exp(4 * (v @ u - 1)) for a, u in zip(rng.uniform(-0.25, 0.3, 6), directions, strict=True))
    v = v * (1 + bumps)[:, None]
    v = v / (np.ptp(v, axis=0) / np.asarray(axes, float))
    return v - (v.max(0) + v.min(0)) / 2, np.asarray(sphere.faces)
