"""Targets: rigid unions of boxes (analytic) and triangle meshes, in the target frame t.

The presets follow DECISIONS.md "Targets": N1 is the Sich-2-1 body box 0.940 × 0.840 ×
0.740 m along x_t, y_t, z_t, centred at O_t; N5 adds four 0.570 × 0.016 × 0.696 m solar
panels, two on each ±x face, centred at (±0.755, 0, ±0.348) m. The paper does not give the
panel arrangement; this one reproduces its cloud sizes to within 3 %.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import as_float_array, check_rotation


class Boxes(eqx.Module):
    """A rigid union of boxes, in the target frame t (metres).

    **Fields:**

    - `centers`: `(B, 3)` box centres.
    - `half_sizes`: `(B, 3)` half edge lengths along each box's own axes, all > 0.
    - `rotations`: `(B, 3, 3)` box-to-target rotations (columns = box axes in frame t).
    """

    centers: Float[Array, "B 3"]
    half_sizes: Float[Array, "B 3"]
    rotations: Float[Array, "B 3 3"]

    @classmethod
    def create(cls, centers, sizes, rotations=None) -> Boxes:
        """Checked constructor from full edge lengths `sizes` (B, 3); raises ValueError on bad input."""
        c = as_float_array(centers, "centers", (None, 3))
        s = as_float_array(sizes, "sizes", (c.shape[0], 3))
        if c.shape[0] == 0:
            raise ValueError("a target needs at least one box.")
        if np.any(s <= 0):
            raise ValueError("box sizes must all be positive (metres).")
        if rotations is None:
            r = np.broadcast_to(np.eye(3), (c.shape[0], 3, 3))
        else:
            r = as_float_array(rotations, "rotations", (c.shape[0], 3, 3))
            for i, ri in enumerate(r):
                check_rotation(ri, f"rotations[{i}]")
        f = jnp.result_type(float)
        return cls(jnp.asarray(c, f), jnp.asarray(s / 2, f), jnp.asarray(r, f))

    @property
    def num_boxes(self) -> int:
        return self.centers.shape[0]

    def triangles(self) -> Float[Array, "T 3 3"]:
        """The boxes as a triangle soup (12 triangles per box), target frame, metres."""
        corners = jnp.array(
            [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float
        )  # index = 4*ix + 2*iy + iz
        faces = jnp.array(
            [
                [0, 1, 3],
                [0, 3, 2],
                [4, 6, 7],
                [4, 7, 5],
                [0, 4, 5],
                [0, 5, 1],
                [2, 3, 7],
                [2, 7, 6],
                [0, 2, 6],
                [0, 6, 4],
                [1, 5, 7],
                [1, 7, 3],
            ]
        )
        verts = (corners[None] * self.half_sizes[:, None, :]) @ jnp.swapaxes(self.rotations, 1, 2)
        verts = verts + self.centers[:, None, :]
        return verts[:, faces].reshape(-1, 3, 3)


class Mesh(eqx.Module):
    """A triangle mesh (any triangle soup), in the target frame t, metres.

    **Fields:**

    - `triangles`: `(T, 3, 3)` the three vertices of each triangle.
    """

    triangles: Float[Array, "T 3 3"]

    @classmethod
    def create(cls, vertices, faces) -> Mesh:
        """Checked constructor from `vertices` (V, 3) and integer `faces` (T, 3)."""
        v = as_float_array(vertices, "vertices", (None, 3))
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"faces: expected integer shape (T, 3), got {f.dtype} {f.shape}.")
        if f.shape[0] == 0:
            raise ValueError("a mesh needs at least one triangle.")
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError("faces: vertex index out of range.")
        return cls(jnp.asarray(v[f], jnp.result_type(float)))

    @classmethod
    def load(cls, path: str, scale: float = 1.0) -> Mesh:
        """Load an STL/OBJ/PLY/… file through trimesh (optional extra `jaxpose[mesh]`).

        `scale` converts the file's unit to metres (e.g. 0.001 for millimetres).
        """
        try:
            import trimesh
        except ImportError as err:  # pragma: no cover - depends on the environment
            raise ImportError("Mesh.load needs trimesh: pip install 'jaxpose[mesh]'.") from err
        mesh = trimesh.load(path, force="mesh")
        return cls.create(np.asarray(mesh.vertices) * scale, np.asarray(mesh.faces))


Target = Boxes | Mesh


def n1() -> Boxes:
    """Shape N1 of the paper: the Sich-2-1 body, one box 0.940 × 0.840 × 0.740 m centred at O_t."""
    return Boxes.create([[0.0, 0.0, 0.0]], [[0.940, 0.840, 0.740]])


def n5() -> Boxes:
    """Shape N5 of the paper: N1 plus four 0.570 × 0.016 × 0.696 m panels (DECISIONS.md)."""
    x, z = 0.470 + 0.285, 0.348
    centers = [[0.0, 0.0, 0.0]] + [[sx * x, 0.0, sz * z] for sx in (1, -1) for sz in (1, -1)]
    sizes = [[0.940, 0.840, 0.740]] + [[0.570, 0.016, 0.696]] * 4
    return Boxes.create(centers, sizes)


CHIBIS_M_INERTIA = (1.60, 1.16, 1.86)
"""Principal moments of inertia of Chibis-M, kg·m² (RELATED.md A.7)."""

CHIBIS_M_MASS = 40.0
"""Chibis-M's mass, kg (ours: the microsatellite's published launch mass; not in RELATED.md)."""


def chibis_m_body() -> tuple[float, float, float]:
    """Sides (m) of the uniform box of mass `CHIBIS_M_MASS` with the moments `CHIBIS_M_INERTIA`:
    from I_x = m(b² + c²)/12 etc., a² = 6(I_y + I_z − I_x)/m (and cyclically)."""
    ix, iy, iz = CHIBIS_M_INERTIA
    k = 6.0 / CHIBIS_M_MASS
    return (float(np.sqrt(k * (iy + iz - ix))), float(np.sqrt(k * (ix + iz - iy))), float(np.sqrt(k * (ix + iy - iz))))


def chibis_m(rod: float = 0.02) -> Boxes:
    """A Chibis-M-like target (ours; RELATED.md gives no drawing): the body box that matches
    the report's inertia at 40 kg (0.46 × 0.59 × 0.37 m, `chibis_m_body`), two 1.0 m antenna
    rods along ±x_t from the centres of the ±x faces (the report finds its long antennas as the
    extreme points along X) and two 0.3 m rods along +z_t from two corners of the +z face
    (its two small antennas). Rods are `rod` × `rod` m square in section."""
    a, b, c = chibis_m_body()
    long_, short = 1.0, 0.3
    centers = [[0.0, 0.0, 0.0]]
    sizes = [[a, b, c]]
    for sx in (1, -1):
        centers.append([sx * (a / 2 + long_ / 2), 0.0, 0.0])
        sizes.append([long_, rod, rod])
    for sy in (1, -1):
        centers.append([a / 2 - rod, sy * (b / 2 - rod), c / 2 + short / 2])
        sizes.append([rod, rod, short])
    return Boxes.create(centers, sizes)


def _mesh(*parts) -> Mesh:
    tris = np.concatenate(parts)
    return Mesh(jnp.asarray(tris, jnp.result_type(float)))


def satellite() -> Mesh:
    """A satellite 3.8 m across (ours): a cylindrical bus (radius 0.55 m, 1.4 m long along z_t),
    two 1.2 × 0.6 m solar wings on booms along ±y_t, and a 0.7 m dish on a mast off the +z
    end, offset from the axis; a thruster block under the −z end. Mesh, about 300 triangles."""
    from . import _shapes as shapes

    parts = [shapes.frustum(0.55, 0.55, 1.4, "z")]
    for s in (1, -1):
        parts.append(shapes.box((0.04, 0.15, 0.04), (0, s * 0.625, 0.2)))
        parts.append(shapes.box((0.6, 1.2, 0.02), (0, s * 1.3, 0.2)))
    parts.append(shapes.frustum(0.03, 0.03, 0.25, "z", (0.2, 0.0, 0.825), segments=8, caps=False))
    parts.append(shapes.dish(0.35, 0.12, "z", (0.2, 0.0, 0.95)))
    parts.append(shapes.box((0.25, 0.2, 0.15), (-0.25, 0.15, -0.775)))
    return _mesh(*parts)


def upper_stage() -> Mesh:
    """A spent upper stage 2.6 m long (ours): a capped cylinder (radius 0.5 m, 2.0 m long along
    x_t), a nozzle (0.15 → 0.4 m radius, 0.6 m long) behind it, a cable tunnel along its side,
    an adapter ring at the front and a small fitting. Nearly axisymmetric: only the fittings
    fix the roll about x_t. Mesh, about 250 triangles."""
    from . import _shapes as shapes

    parts = [shapes.frustum(0.5, 0.5, 2.0, "x", (0.3, 0, 0))]
    parts.append(shapes.frustum(0.4, 0.15, 0.6, "x", (-1.0, 0, 0), caps=False))
    parts.append(shapes.box((1.6, 0.06, 0.05), (0.3, 0.0, 0.52)))
    parts.append(shapes.frustum(0.42, 0.42, 0.08, "x", (1.34, 0, 0), caps=False))
    parts.append(shapes.box((0.15, 0.15, 0.12), (0.6, 0.47, -0.1)))
    return _mesh(*parts)


def fragment() -> Mesh:
    """An irregular fragment (ours): a 1.4 × 0.9 m panel with a torn outline, folded by 35°
    along a line across it, with a stiffener along one edge. Open surfaces, about 130 triangles."""
    from . import _shapes as shapes

    panel = shapes.torn_panel(1.4, 0.9, np.radians(35.0), seed=7)
    stiffener = shapes.box((0.8, 0.04, 0.04), (-0.2, -0.36, 0.02))
    return _mesh(panel, stiffener)


DEBRIS_FILE = "data/debris.obj"
"""A rock-like closed mesh 1.6 × 1.1 × 0.8 m in the package (`shapes.rock`), loaded from the
file so that the benchmark exercises [`Mesh.load`][jaxpose.targets.Mesh.load]."""


def debris() -> Mesh:
    """The packaged rock-like mesh (`DEBRIS_FILE`), loaded through `Mesh.load` (needs trimesh)."""
    from importlib.resources import files

    return Mesh.load(str(files("jaxpose") / DEBRIS_FILE))


def scaled(target: Target, factor: float) -> Target:
    """`target` with every length multiplied by `factor` (> 0), about the target frame's
    origin O_t: the same shape, `factor` times as large (metres)."""
    if not factor > 0:
        raise ValueError(f"scaled: factor must be > 0, got {factor!r}.")
    if isinstance(target, Boxes):
        return Boxes(target.centers * factor, target.half_sizes * factor, target.rotations)
    return Mesh(target.triangles * factor)


BUILT_IN = ("n1", "n5", "chibis_m", "satellite", "upper_stage", "fragment", "debris")
"""The names of the built-in targets (functions of this module)."""
