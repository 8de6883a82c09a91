"""The objectives f(p) ∈ [0, 1]: the paper's hard-cell reference and our soft histogram.

Both take a displacement p = (θ, φ, ψ, x, y, z) — radians and metres, frame ν relative to
frame n — and a [`jaxpose.Problem`][]; both are pure, jittable, and vmap over p and over
problems. f = mean over planes of (s_{n→ν} + s_{ν→n}) / 2 (METHOD.md §9, DECISIONS.md).

Evaluation strategy (per candidate): the current points are moved into frame ν with nine
multiply-adds on structure-of-arrays coordinates; the backward score s_{ν→n} is a *gather*
of the precomputed field r·M_prev at each current point's cell (each point carries its
cell's k by being counted once); the forward score s_{n→ν} needs the current occupancy, one
scatter over all planes, then a gather at the 9 neighbours of each filled previous cell.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._problem import NEIGHBOUR_OFFSETS, NEIGHBOUR_WEIGHTS, Problem, round_half_up
from ._rotations import into_moved_frame


def to_moved_frame(p: Float[ArrayLike, "6"], problem: Problem) -> tuple[Array, Array, Array]:
    """Current points in the moved frame ν for candidate p: q = G(θ, φ, ψ)ᵀ (b − (x, y, z)),
    with b the points in frame n (METHOD.md §5). Structure of arrays, metres."""
    return into_moved_frame(jnp.asarray(p), problem.curr[0], problem.curr[1], problem.curr[2])


def _ratio(num, den):
    """num/den, and 0 where den = 0 (an empty pattern scores 0, never NaN)."""
    safe = jnp.where(den > 0, den, 1.0)
    return jnp.where(den > 0, num / safe, 0.0)


def _forward(occupancy: Float[Array, " F"], problem: Problem) -> Float[Array, " P"]:
    """s_{n→ν} of each plane: Σ k r · max_Q exp(−δ)·occupancy / Σ k r over filled previous cells."""
    stride = problem.grid_cells + 2
    best = jnp.zeros_like(problem.prev_kr)
    for (da, db), w in zip(NEIGHBOUR_OFFSETS, NEIGHBOUR_WEIGHTS, strict=True):
        best = jnp.maximum(best, w * occupancy[problem.prev_cells + da * stride + db])
    num = jax.ops.segment_sum(problem.prev_kr * best, problem.prev_plane, problem.num_planes)
    return _ratio(num, problem.kr_sum)


def hard_score(p: Float[ArrayLike, "6"], problem: Problem) -> Float[Array, ""]:
    """The paper's objective f(p) with hard selection and hard cells (the reference).

    A current point is selected for plane i when its distance to the plane is ≤ d; it falls
    in the cell nearest to it (round half up) and is dropped outside the grid. Per filled
    cell: max over the 3 × 3 neighbourhood Q of exp(−δ in cells) for filled cells of the
    other pattern, times the cell's own k·r. Piecewise constant in p.

    **Returns:** f ∈ [0, 1], a scalar.
    """
    q = to_moved_frame(p, problem)
    flats, bwd = [], []
    for i in range(problem.num_planes):
        h, a, b = problem.plane_coords(q, i)
        a, b = round_half_up(a), round_half_up(b)
        inside = problem.curr_valid & (jnp.abs(h) <= problem.d) & problem.in_grid(i, a, b)
        flat = problem.flat_index(i, a, b, inside)
        flats.append(flat)
        bwd.append(_ratio(jnp.sum(problem.rm_field[flat]), jnp.sum(problem.r_field[flat])))
    occupancy = jnp.zeros_like(problem.r_field).at[jnp.concatenate(flats)].set(1.0)
    occupancy = occupancy.at[problem.dump].set(0.0)
    s = (_forward(occupancy, problem) + jnp.stack(bwd)) / 2
    return jnp.mean(s)


def _smoothstep(x):
    """0 for x ≤ 0, 1 for x ≥ 1, 3x² − 2x³ between: C¹."""
    x = jnp.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _cell_kernel(x, width):
    """Weight of a cell whose centre is x cells away: a box of one cell with C¹ edges of
    `width` cells (0 < width ≤ 1). Weights of all cells sum to 1 exactly; support |x| <
    (1 + width)/2 ≤ 1, so a point touches at most 2 cells per axis. → box as width → 0."""
    return _smoothstep((x + 0.5) / width + 0.5) - _smoothstep((x - 0.5) / width + 0.5)


def soft_score(p: Float[ArrayLike, "6"], problem: Problem) -> Float[Array, ""]:
    """A continuous, differentiable relaxation of [`hard_score`][] (ours, not the paper's).

    Hard indicators become C¹ kernels: selection weight S((d − |h|)/(w_s d) + ½) with
    w_s = `select_width`; each point is split over the (at most) 2 × 2 nearest cells by a
    one-cell box kernel with edges of `bin_width` cells; a current cell's occupancy is the
    smoothstep of its soft count (1 once the count reaches one point). The radii r and the
    previous side (k, M_prev) stay as in the hard objective. As both widths → 0 the value
    tends to `hard_score` (tested); with finite widths it resolves sub-cell shifts.

    **Returns:** f ∈ [0, 1], a scalar, differentiable in p almost everywhere (the max over
    the neighbourhood has kinks).
    """
    q = to_moved_frame(p, problem)
    tiny = jnp.finfo(problem.d.dtype).tiny
    w_sel = jnp.maximum(problem.select_width, tiny) * problem.d
    w_bin = jnp.clip(problem.bin_width, tiny, 1.0)
    flats, weights, bwd = [], [], []
    for i in range(problem.num_planes):
        h, a, b = problem.plane_coords(q, i)
        sel = jnp.where(problem.curr_valid, _smoothstep((problem.d - jnp.abs(h)) / w_sel + 0.5), 0.0)
        a0, b0 = jnp.floor(a), jnp.floor(b)
        fa, fb = a - a0, b - b0
        a0, b0 = a0.astype(jnp.int32), b0.astype(jnp.int32)
        num = den = 0.0
        for da in (0, 1):
            for db in (0, 1):
                w = sel * _cell_kernel(fa - da, w_bin) * _cell_kernel(fb - db, w_bin)
                ca, cb = a0 + da, b0 + db
                flat = problem.flat_index(i, ca, cb, problem.in_grid(i, ca, cb))
                num = num + jnp.sum(w * problem.rm_field[flat])
                den = den + jnp.sum(w * problem.r_field[flat])
                flats.append(flat)
                weights.append(w)
        bwd.append(_ratio(num, den))
    counts = jnp.zeros_like(problem.r_field).at[jnp.concatenate(flats)].add(jnp.concatenate(weights))
    occupancy = _smoothstep(counts).at[problem.dump].set(0.0)
    s = (_forward(occupancy, problem) + jnp.stack(bwd)) / 2
    return jnp.mean(s)
