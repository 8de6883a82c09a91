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

from ._checks import as_float_array, check_rotation


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
