"""The `Problem`: everything about a cloud pair that does not depend on the candidate p.

Built once per pair (DECISIONS.md "Patterns and grid"): the plane frame n of the previous
cloud, its intersection patterns on each cutting plane, each plane's grid (lo, m, the
extension e), the previous cells' counts k and radii r, and the current cloud's valid points
in frame n. All arrays have static shapes set by the [`jaxpose.Config`][] capacities, so a
`Problem` jits, vmaps over pairs, and is the `args` of the scoring functions.

Grid layout: plane i owns a `(C + 2) × (C + 2)` block of a flat array (C = `grid_cells`);
grid cell (a, b), 0 ≤ a, b < C, sits at `i·(C+2)² + (a+1)·(C+2) + (b+1)`, so the 3 × 3
neighbourhood of any cell stays inside its block. The last slot of the flat array is a dump
that holds zeros: points that are not selected or fall outside the grid go there.
Cell index of a coordinate η: `a = floor((η − lo)/d + 1/2) + e` (round half up).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._checks import is_concrete
from ._cloud import Cloud
from ._config import Config
from ._fine import CurrentSide, FineCloud, back_side, current_side, fine_cloud
from ._frame import FRAME_STATUS_TEXT, MIN_POINTS, PlaneFrame, plane_frame
from ._neighbours import spread_subset, voxel_spacing
from ._programs import BoundedJit

# Bits of Problem.status.
PROBLEM_FRAME = 1  # the plane frame is not usable (see frame.status)
PROBLEM_GRID_OVERFLOW = 2  # a previous pattern's grid exceeded grid_cells; outer cells dropped
PROBLEM_CELLS_OVERFLOW = 4  # a previous pattern filled more than max_cells cells
PROBLEM_POINTS_OVERFLOW = 8  # the current cloud has more than max_points valid points
PROBLEM_FEW_CURRENT = 16  # the current cloud has fewer valid points than frame.MIN_POINTS
PROBLEM_PREV_OVERFLOW = 32  # the previous cloud has more than max_prev_points valid points

NEIGHBOUR_OFFSETS = tuple((a, b) for a in (-1, 0, 1) for b in (-1, 0, 1))
"""The 3 × 3 neighbourhood Q, as (Δa, Δb) in cells."""
NEIGHBOUR_WEIGHTS = tuple(math.exp(-math.hypot(a, b)) for a, b in NEIGHBOUR_OFFSETS)
"""exp(−distance in cells) of each offset (DECISIONS.md: distances measured in cells)."""


class Problem(eqx.Module):
    """A cloud pair prepared for scoring candidate displacements p.

    **Fields** (P = number of planes, C = grid capacity; lengths in metres, frame n):

    - `frame`: the [`jaxpose.PlaneFrame`][] n of the previous cloud.
    - `d`, `bin_width`, `select_width`: from the config.
    - `curr`: `(3, M)` current valid points in frame n (structure of arrays, zero padded).
    - `curr_valid`: `(M,)` mask of `curr`.
    - `lo`: `(P, 2)` smallest previous (η, ζ) of each plane's pattern (0 if empty).
    - `ext`, `size`: `(P, 2)` extension e and cell count (m + 2e + 1, capped at C).
    - `prev_cells`, `prev_kr`, `prev_plane`: the filled previous cells (flat indices),
      their weights k·r and plane index, padded with zero weight to P·max_cells.
    - `kr_sum`: `(P,)` Σ k·r of each previous pattern.
    - `r_field`, `rm_field`: per flat cell, r (cell centre to the plane's 2D origin) and
      r·M_prev, where M_prev(c) = max over Q(c) of exp(−δ)·[previous cell filled]; zero
      outside each grid and in the dump.
    - `prev_selected`, `prev_filled`: `(P,)` selected points and filled cells per plane.
    - `fine`: the previous side of the fine stage (`FineCloud`; one empty
      slot when `Config.fine` is None).
    - `status`: bit flags `PROBLEM_*` (0 = usable), the coarse problem's included.
    - `planes`, `grid_cells`: static.
    - `coarse`: the coarse problem the global search scores (`GlobalSearch.coarse_factor` > 1: cells of
      coarse·d, `coarse_points` current points thinned evenly, no fine stage; same frame n),
      or None.
    - `fine_curr`: the fine stage's current side, with its face-like points smoothed
      (`CurrentSide`), or None where `FineStage.smooth_current` is false (or no fine stage).
    - `fine_back`: the current points with their planes (`FineCloud`, frame n), which the
      previous points are matched against where `FineStage.symmetric`; None elsewhere.
    """

    frame: PlaneFrame
    d: Float[Array, ""]
    bin_width: Float[Array, ""]
    select_width: Float[Array, ""]
    curr: Float[Array, "3 M"]
    curr_valid: Bool[Array, " M"]
    lo: Float[Array, "P 2"]
    ext: Int[Array, "P 2"]
    size: Int[Array, "P 2"]
    prev_cells: Int[Array, " L"]
    prev_kr: Float[Array, " L"]
    prev_plane: Int[Array, " L"]
    kr_sum: Float[Array, " P"]
    r_field: Float[Array, " F"]
    rm_field: Float[Array, " F"]
    prev_selected: Int[Array, " P"]
    prev_filled: Int[Array, " P"]
    fine: FineCloud
    status: Int[Array, ""]
    planes: tuple[tuple[int, float], ...] = eqx.field(static=True)
    grid_cells: int = eqx.field(static=True)
    coarse: Problem | None = None
    fine_curr: CurrentSide | None = None
    fine_back: FineCloud | None = None

    @property
    def search_problem(self) -> Problem:
        """The problem the global search scores: `coarse` if there is one, else this one."""
        return self if self.coarse is None else self.coarse

    @property
    def num_planes(self) -> int:
        return len(self.planes)

    @property
    def block(self) -> int:
        """Flat size of one plane's padded grid, (C + 2)²."""
        return (self.grid_cells + 2) ** 2

    @property
    def dump(self) -> int:
        """Flat index of the dump slot."""
        return self.num_planes * self.block

    def flat_index(self, plane: int, a: Array, b: Array, inside: Array) -> Array:
        """Flat index of cell (a, b) of `plane`, or the dump where `inside` is false."""
        flat = plane * self.block + (a + 1) * (self.grid_cells + 2) + (b + 1)
        return jnp.where(inside, flat, self.dump)

    def plane_coords(self, q: tuple[Array, Array, Array], plane: int):
        """For current points q (frame ν, SoA): distance to `plane`, and continuous cell
        coordinates (a, b) on its grid (cell centres at integers)."""
        j, offset = self.planes[plane]
        h = q[j] - offset * self.d
        a = (q[(j + 1) % 3] - self.lo[plane, 0]) / self.d + self.ext[plane, 0]
        b = (q[(j + 2) % 3] - self.lo[plane, 1]) / self.d + self.ext[plane, 1]
        return h, a, b

    def in_grid(self, plane: int, a: Array, b: Array) -> Array:
        return (a >= 0) & (a < self.size[plane, 0]) & (b >= 0) & (b < self.size[plane, 1])

    @classmethod
    def build(cls, prev: Cloud, curr: Cloud, config: Config | None = None) -> Problem:
        """Prepare a cloud pair (both in the camera frame c) for scoring.

        Pure and jittable. At the Python boundary (concrete inputs) it raises ValueError for
        an unusable pair: fewer than 10 valid points, a flat or ambiguous previous cloud, or
        a pattern/cloud that exceeds the config's capacities (the message names the field to
        raise). Under jit the same conditions set bits of `status`.
        """
        config = Config() if config is None else config
        if is_concrete(prev, curr):
            prev.check("previous cloud")
            curr.check("current cloud")
            check_range(prev, curr, config)
            prev, curr = prev.floating(), curr.floating()
            config = sized_config(prev, curr, config)
        else:
            config = config.with_jit_capacities(prev.points.shape[-2], curr.points.shape[-2])
        problem = run_growing(lambda grown: _with_status(build_problem(prev, curr, grown)), config)[0]
        if is_concrete(problem):
            raise_for_status(problem)
        return problem


def bucket(count: int, least: int = 64) -> int:
    """The smallest capacity ≥ `count` among least · 2^k: at most twice the need, and few sizes,
    so that a stream of similar clouds reuses one compiled program and a benchmark over many
    targets and distances compiles a few dozen (a finer ladder, least · {1, 1.5} · 2^k, gave
    80 programs for the 112 pairs of `make_cases(4)`; this one 25)."""
    size = least
    while size < count:
        size *= 2
    return size


POINTS_LEAST, GRID_LEAST, CELLS_LEAST = 2048, 64, 512
"""The smallest sized capacities (points, grid cells per axis, pattern cells): below them a
program costs little more, and small clouds then share one."""

GRID_MARGIN = 4
"""Cells added to the largest previous pattern's grid when sizing `grid_cells`: the coarse
level's grid, ⌈C / coarse⌉ + 2 cells, then holds its own rounding of m and e."""


def sized_config(prev: Cloud, curr: Cloud, config: Config) -> Config:
    """`config` with every capacity left at None sized from the clouds (Python boundary only):
    the larger valid count for `max_points` and `max_prev_points`, the largest previous pattern's
    grid for `grid_cells` and its selected points (an upper bound of its filled cells) for
    `max_cells`, each rounded up by [`bucket`][]. Capacities the config sets are kept.

    A pair the build would refuse for its plane frame, or for a current cloud of fewer than
    `MIN_POINTS` valid points, raises its ValueError here, before the pair's program compiles."""
    n_prev, grid, selected, frame_status = (int(x) for x in _pattern_sizes(prev, config))
    n_curr = int(np.sum(np.asarray(curr.valid)))
    if frame_status:
        raise_for_codes(PROBLEM_FRAME, frame_status)
    if n_curr < MIN_POINTS:
        raise_for_codes(PROBLEM_FEW_CURRENT, 0)
    return _filled(config, max(n_prev, n_curr), grid, selected)


def sized_sequence_config(clouds: Cloud, config: Config) -> Config:
    """`config` sized for a sequence of clouds (leading axis T) in which any frame may be the
    previous cloud of a pair (a tracker's keyframe) and any the current one: the largest valid
    count, pattern grid and pattern selection over the frames, rounded as [`sized_config`][].
    Python boundary only."""
    return _filled(config, *_largest_sizes(clouds, config))


def _largest_sizes(clouds: Cloud, config: Config) -> tuple[int, int, int]:
    """The largest valid count, pattern grid and pattern selection over clouds stacked along a
    leading axis, in one vmapped program (`_sizes_of_patterns` per cloud)."""
    counts, grids, selected, _ = eqx.filter_vmap(lambda c: _pattern_sizes(c, config))(clouds)
    return int(jnp.max(counts)), int(jnp.max(grids)), int(jnp.max(selected))


def sized_batch_config(pairs: Sequence[tuple[Cloud, Cloud]], config: Config) -> Config:
    """`config` sized for a batch of (previous, current) pairs that run under one compiled
    program (a vmapped or sharded batch): the largest valid count, pattern grid and pattern
    selection over the pairs, rounded as [`sized_config`][]. Python boundary only."""
    sizes = [tuple(int(x) for x in _pattern_sizes(prev, config))[:3] for prev, _ in pairs]
    counts = [n for n, _, _ in sizes] + [int(np.sum(np.asarray(curr.valid))) for _, curr in pairs]
    return _filled(config, max(counts), max(g for _, g, _ in sizes), max(s for _, _, s in sizes))


def sized_stacked_config(prev: Cloud, curr: Cloud, config: Config) -> Config:
    """[`sized_batch_config`][] for pairs stacked along a leading batch axis (points
    `(B, N, 3)` and `(B, M, 3)`): the previous clouds' pattern sizes in one vmapped program
    instead of one call per pair. Python boundary only."""
    count, grid, selected = _largest_sizes(prev, config)
    n_curr = int(np.max(np.sum(np.asarray(curr.valid), axis=-1)))
    return _filled(config, max(count, n_curr), grid, selected)


def _filled(config: Config, points: int, grid: int, selected: int) -> Config:
    """`config` with each capacity left at None set from the sizes of the data: `points` valid
    points (both clouds), a largest pattern grid of `grid` cells per axis and `selected`
    points in the fullest pattern, each rounded up by [`bucket`][]."""
    points = bucket(points, POINTS_LEAST)  # one size for both clouds: a stream shares it
    fill = {
        "max_points": points,
        "max_prev_points": points,
        "grid_cells": bucket(grid + GRID_MARGIN, GRID_LEAST),
        "max_cells": bucket(selected, CELLS_LEAST),
    }
    return config.with_capacities(**fill)


CELL_STEP_SAMPLES = 64
"""Points whose nearest-neighbour distances give the sampling step of [`cell_size`][]. The
sizing at the Python boundary measures it over the whole frame (every pixel a row: 41 616 for
the CamCube), where 256 samples cost 14 ms a call on the 2-core CPU and 64 cost a quarter;
the median of 64 distances fixes a scale to a few per cent."""


def cell_size(points: Float[Array, "N 3"], valid: Bool[Array, " N"], config: Config) -> Float[Array, ""]:
    """The cell size and selection half-width d (metres) of the patterns of a previous cloud
    (points in any frame, `valid` its mask): `Patterns.d`, or `Patterns.cell_steps` times the
    cloud's sampling step (median nearest-neighbour distance) where that is larger. Jittable;
    the build and the sizing at the Python boundary both take d from here."""
    floor = jnp.asarray(config.patterns.d, points.dtype)
    if isinstance(config.patterns.cell_steps, int | float) and config.patterns.cell_steps == 0:
        return floor  # the default: no step search compiled into the sizing and the build
    steps = jnp.asarray(config.patterns.cell_steps, points.dtype)
    step = jax.lax.cond(
        steps > 0, lambda: voxel_spacing(points.T, valid, CELL_STEP_SAMPLES), lambda: jnp.zeros((), points.dtype)
    )
    return jnp.maximum(floor, steps * step)


def with_cell(config: Config, d) -> Config:
    """`config` with its patterns' cell fixed at `d` (metres): `Patterns.d` = d and
    `cell_steps` = 0, so that nothing downstream sizes the cell again."""
    return dataclasses.replace(config, patterns=dataclasses.replace(config.patterns, d=d, cell_steps=0.0))


def _sizes_of_patterns(prev: Cloud, config: Config):
    """The previous cloud's valid count, its largest pattern grid (cells per axis, before the
    cap), the most points any pattern selects, at the cell of [`cell_size`][], and its plane
    frame's status, for [`sized_config`][] (compiled as `_pattern_sizes`)."""
    frame = plane_frame(prev)
    A = jnp.where(prev.valid[:, None], frame.to_frame(prev.masked_points), 0.0)
    d = cell_size(A, prev.valid, config)
    grids = [
        _plane_grid(A, prev.valid, j, offset, d, config.patterns.extension) for j, offset in config.patterns.planes()
    ]
    return (
        jnp.sum(prev.valid),
        jnp.max(jnp.stack([jnp.max(jnp.stack(g.size)) for g in grids])),
        jnp.max(jnp.stack([jnp.sum(g.selected) for g in grids])),
        frame.status,
    )


_pattern_sizes = BoundedJit(_sizes_of_patterns)
"""One compiled program per cloud size (kept on disk with `enable_compile_cache`, so that a
new process sizes its first pair without tracing it)."""


def check_range(prev: Cloud, curr: Cloud, config: Config) -> None:
    """Refuse clouds beyond `config.thresholds.max_range`, or so far out that the float type cannot
    resolve d/10 there (both mean the data are not lidar returns in metres)."""
    for name, cloud in (("previous cloud", prev), ("current cloud", curr)):
        check_reach(name, np.asarray(cloud.points), np.asarray(cloud.valid), config)


def check_reach(name: str, points: np.ndarray, valid: np.ndarray, config: Config) -> None:
    """[`check_range`][] for one cloud given as host (numpy) arrays, `name` leading the message.
    The points are masked in numpy, as `Cloud.masked_points` masks them: a check at the Python
    boundary then costs no device op or transfer beyond one copy of the arrays (on an
    accelerator, each op is a round trip)."""
    dtype = points.dtype if jnp.issubdtype(points.dtype, jnp.floating) else jnp.result_type(float)
    pts = np.abs(np.where(valid[..., None], points, 0).astype(dtype))
    far = float(pts.max()) if pts.size else 0.0
    if far > config.thresholds.max_range:
        raise ValueError(
            f"{name}: points reach {far:.3g} m from the camera, beyond Config.thresholds.max_range = "
            f"{config.thresholds.max_range:g} m. Check the units (metres) or raise max_range."
        )
    d = config.patterns.d
    resolution = far * float(np.finfo(pts.dtype).eps)
    if resolution > d / 10:
        raise ValueError(
            f"{name}: points reach {far:.3g} m from the camera, out of range for {pts.dtype} "
            f"(resolution {resolution:.2g} m there, coarser than d/10 = {d / 10:.2g} m). "
            "Recentre the clouds near the camera origin or enable float64 (jax_enable_x64)."
        )


def raise_for_status(problem: Problem) -> None:
    """Raise a ValueError that names the problem and its fix, if `problem.status` is not 0."""
    raise_for_codes(int(problem.status), int(problem.frame.status))


def grow_capacities(config: Config, status: int) -> Config | None:
    """`config` with each capacity that `status` reports overflowed doubled, or None when none
    did. The Python boundary runs a pair again with it, so a capacity is never the user's."""
    grow = {
        PROBLEM_GRID_OVERFLOW: "grid_cells",
        PROBLEM_CELLS_OVERFLOW: "max_cells",
        PROBLEM_POINTS_OVERFLOW: "max_points",
        PROBLEM_PREV_OVERFLOW: "max_prev_points",
    }
    fields = {name: 2 * getattr(config.capacities, name) for bit, name in grow.items() if status & bit}
    return dataclasses.replace(config, capacities=dataclasses.replace(config.capacities, **fields)) if fields else None


GROW_TRIES = 4
"""Compiled calls the Python boundary makes for one input at most: a capacity that the sizing
missed (a rounding at the coarse level) is doubled and the input run again."""


def run_growing(run: Callable[[Config], tuple], config: Config, tries: int = GROW_TRIES) -> tuple:
    """`run(config)`, run again with each overflowed capacity doubled until none overflowed,
    at most `tries` times, so that a capacity is never the user's problem.

    `run` returns a tuple whose second item is a problem status (bits `PROBLEM_*`) of any
    shape, one per pair of a batch; a capacity any pair overflowed grows. A traced status
    (under jit) returns the first run as it is: the caller's status then reports it."""
    for _ in range(tries):
        out = run(config)
        if not is_concrete(out[1]):
            return out
        grown = grow_capacities(config, int(np.bitwise_or.reduce(np.ravel(np.asarray(out[1])))))
        if grown is None:
            return out
        config = grown
    return out


def _with_status(problem: Problem) -> tuple[Problem, Int[Array, ""]]:
    return problem, problem.status


def raise_for_codes(status: int, frame_status: int) -> None:
    """Raise a ValueError that names the problem and its fix, for a problem status (bits
    `PROBLEM_*`) and its frame's status; nothing when both are 0."""
    if status & PROBLEM_FRAME:
        raise ValueError(
            "previous cloud: "
            + FRAME_STATUS_TEXT[frame_status]
            + "; the plane frame cannot be built. Give a cloud of a 3D object with distinct spreads."
        )
    if status & PROBLEM_FEW_CURRENT:
        raise ValueError("current cloud: fewer than 10 valid points.")
    if status & PROBLEM_POINTS_OVERFLOW:
        raise ValueError("current cloud has more valid points than Capacities.max_points; raise it.")
    if status & PROBLEM_PREV_OVERFLOW:
        raise ValueError("previous cloud has more valid points than Capacities.max_prev_points; raise it.")
    if status & PROBLEM_GRID_OVERFLOW:
        raise ValueError("a previous pattern is larger than the grid; raise Capacities.grid_cells (or Patterns.d).")
    if status & PROBLEM_CELLS_OVERFLOW:
        raise ValueError("a previous pattern fills more cells than Capacities.max_cells; raise it.")


def neighbourhood_max(occupancy: Float[Array, "... C2 C2"]) -> Float[Array, "... C2 C2"]:
    """max over the 3 × 3 neighbourhood of exp(−distance in cells) · occupancy (zero border)."""
    padded = jnp.pad(occupancy, [(0, 0)] * (occupancy.ndim - 2) + [(1, 1), (1, 1)])
    n0, n1 = occupancy.shape[-2:]
    out = jnp.zeros_like(occupancy)
    for (da, db), w in zip(NEIGHBOUR_OFFSETS, NEIGHBOUR_WEIGHTS, strict=True):
        out = jnp.maximum(out, w * padded[..., 1 + da : 1 + da + n0, 1 + db : 1 + db + n1])
    return out


def round_half_up(x) -> Array:
    """round(x) with halves rounded up, as int32: the cell-index rule of the grids."""
    return jnp.floor(x + 0.5).astype(jnp.int32)


def _build(prev: Cloud, curr: Cloud, config: Config) -> Problem:
    curr = Cloud(curr.masked_points, curr.valid)
    # The previous cloud compacted to its valid points first: the frame, the patterns at each
    # level and the fine stage's side then touch max_prev_points rows, not the whole frame
    # (41 616 pixels for 4 194 points on the paper's N5). Rows stay in order. (On overflow the
    # frame is that of the first max_prev_points points, and the status says so.)
    n_prev = jnp.sum(prev.valid)
    prev = prev.packed(config.capacities.max_prev_points)
    live = prev.valid
    frame = plane_frame(prev)
    A = jnp.where(live[:, None], frame.to_frame(prev.points), 0.0)
    config = with_cell(config, cell_size(A, live, config))
    status = jnp.where(frame.ok, 0, PROBLEM_FRAME) | jnp.where(
        n_prev > config.capacities.max_prev_points, PROBLEM_PREV_OVERFLOW, 0
    )
    coarse = None
    if config.search.coarse_factor > 1:
        # Thinned evenly over the valid points (in scan order: evenly over the image).
        idx, sub = spread_subset(curr.valid, config.search.coarse_points)
        thinned = Cloud(curr.points[idx], sub & curr.valid[idx])
        coarse = _problem_at_level(frame, A, live, thinned, config.coarse_config, status)
        status = status | coarse.status
    return _problem_at_level(frame, A, live, curr, config, status, coarse)


build_problem = BoundedJit(_build)
"""The build as one compiled call per capacity bucket (jitted: op by op it cost ≈ 100 ms of
dispatch at the Python boundary, and under `jax.vmap` it crashed XLA:CPU, JAX 0.10.2)."""


class _PlaneGrid(NamedTuple):
    """One previous pattern's grid before the capacity cap (DECISIONS.md "Patterns and grid")."""

    selected: Bool[Array, " N"]  # previous points within d of the plane
    coords: tuple[Array, Array]  # their (η, ζ) on the plane, metres
    lo: list  # smallest selected η and ζ (0 when none is selected)
    ext: list  # extension e per axis, cells
    size: list  # m + 2e + 1 per axis, cells


def _plane_grid(A: Float[Array, "N 3"], valid: Bool[Array, " N"], j: int, offset: float, d, extension) -> _PlaneGrid:
    """The grid of the pattern on the plane with normal axis j at `offset`·d (frame n)."""
    h = A[:, j] - offset * d
    uv = (A[:, (j + 1) % 3], A[:, (j + 2) % 3])
    sel = valid & (jnp.abs(h) <= d)
    any_sel = jnp.any(sel)
    lo = [jnp.where(any_sel, jnp.min(jnp.where(sel, c, jnp.inf)), 0.0) for c in uv]
    hi = [jnp.where(any_sel, jnp.max(jnp.where(sel, c, -jnp.inf)), 0.0) for c in uv]
    m = [round_half_up((h_ - l_) / d) for l_, h_ in zip(lo, hi, strict=True)]
    e = [round_half_up(extension * mk) for mk in m]
    return _PlaneGrid(sel, uv, lo, e, [mk + 2 * ek + 1 for mk, ek in zip(m, e, strict=True)])


class _PlanePattern(NamedTuple):
    """One cutting plane's previous pattern on its grid (see `Problem` for the fields)."""

    lo: Float[Array, "2"]
    ext: Int[Array, "2"]
    size: Int[Array, "2"]
    selected: Int[Array, ""]
    filled: Int[Array, ""]
    r_field: Float[Array, "C2 C2"]
    rm_field: Float[Array, "C2 C2"]
    cells: Int[Array, " L"]
    kr: Float[Array, " L"]
    plane: Int[Array, " L"]
    kr_sum: Float[Array, ""]
    status: Int[Array, ""]


def _plane_pattern(A, prev_valid, i: int, j: int, offset: float, d, config: Config) -> _PlanePattern:
    """Plane i (normal axis j, offset in units of d) of the previous points A (frame n): its
    grid, cell counts k, the fields r and r·M_prev padded by one cell, and its filled cells as
    flat indices of the problem's field with their k·r; overflow bits in `status`."""
    C, max_cells = config.capacities.grid_cells, config.capacities.max_cells
    dtype = A.dtype
    grid = _plane_grid(A, prev_valid, j, offset, d, config.patterns.extension)
    sel, lo, e = grid.selected, grid.lo, grid.ext
    status = jnp.where((grid.size[0] > C) | (grid.size[1] > C), PROBLEM_GRID_OVERFLOW, 0)
    n = [jnp.minimum(nk, C) for nk in grid.size]
    idx = [round_half_up((c - l_) / d) + ek for c, l_, ek in zip(grid.coords, lo, e, strict=True)]
    inside = sel & (idx[0] < n[0]) & (idx[1] < n[1])
    counts = (
        jnp.zeros((C, C), dtype).at[jnp.where(inside, idx[0], C), jnp.where(inside, idx[1], C)].add(1.0, mode="drop")
    )
    filled = counts > 0
    ka, kb = jnp.arange(C), jnp.arange(C)
    in_grid = (ka[:, None] < n[0]) & (kb[None, :] < n[1])
    centre_a = lo[0] + (ka - e[0]).astype(dtype) * d
    centre_b = lo[1] + (kb - e[1]).astype(dtype) * d
    r = jnp.where(in_grid, jnp.hypot(centre_a[:, None], centre_b[None, :]), 0.0)
    m_prev = neighbourhood_max(filled.astype(dtype))

    nfilled = jnp.sum(filled)
    status = status | jnp.where(nfilled > max_cells, PROBLEM_CELLS_OVERFLOW, 0)
    (flat_cells,) = jnp.nonzero(filled.ravel(), size=max_cells, fill_value=0)
    live = jnp.arange(max_cells) < nfilled
    a_c, b_c = flat_cells // C, flat_cells % C
    return _PlanePattern(
        lo=jnp.stack(lo),
        ext=jnp.stack(e),
        size=jnp.stack(n),
        selected=jnp.sum(sel).astype(jnp.int32),
        filled=nfilled.astype(jnp.int32),
        r_field=jnp.pad(r, 1),
        rm_field=jnp.pad(r * m_prev, 1),
        cells=i * (C + 2) ** 2 + (a_c + 1) * (C + 2) + (b_c + 1),
        kr=jnp.where(live, (counts * r).ravel()[flat_cells], 0.0),
        plane=jnp.full(max_cells, i, jnp.int32),
        kr_sum=jnp.sum(counts * r),
        status=status,
    )


def _current_points(frame: PlaneFrame, curr: Cloud, config: Config, dtype):
    """The current cloud's valid points in frame n, compacted to `max_points` slots
    (structure of arrays, zero padded), their mask, and the overflow / too-few bits."""
    n_curr = jnp.sum(curr.valid)
    status = jnp.where(n_curr > config.capacities.max_points, PROBLEM_POINTS_OVERFLOW, 0)
    status = status | jnp.where(n_curr < MIN_POINTS, PROBLEM_FEW_CURRENT, 0)
    packed = curr.packed(config.capacities.max_points)
    B = frame.to_frame(packed.points.astype(dtype))
    return jnp.where(packed.valid[:, None], B, 0.0).T, packed.valid, status


def _problem_at_level(
    frame: PlaneFrame,
    A: Float[Array, "N 3"],
    prev_valid: Bool[Array, " N"],
    curr: Cloud,
    config: Config,
    status: Int[Array, ""],
    coarse: Problem | None = None,
) -> Problem:
    """The problem at one level: previous points A (frame n) and their mask, the current cloud
    (frame c), cells of `config.patterns.d`."""
    dtype = A.dtype
    d = jnp.asarray(config.patterns.d, dtype)
    C = config.capacities.grid_cells
    planes = config.patterns.planes()
    patterns = [_plane_pattern(A, prev_valid, i, j, offset, d, config) for i, (j, offset) in enumerate(planes)]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *patterns)
    curr_n, curr_valid, curr_status = _current_points(frame, curr, config, dtype)
    fine = fine_cloud(A, prev_valid, config, planes, d)
    for pattern in patterns:
        status = status | pattern.status
    status = status | curr_status

    def flat(fields):
        return jnp.concatenate([f.ravel() for f in fields] + [jnp.zeros(1, dtype)])

    return Problem(
        frame=frame,
        d=d,
        bin_width=jnp.asarray(config.patterns.bin_width, dtype),
        select_width=jnp.asarray(config.patterns.select_width, dtype),
        curr=curr_n,
        curr_valid=curr_valid,
        lo=stacked.lo,
        ext=stacked.ext,
        size=stacked.size,
        prev_cells=stacked.cells.ravel().astype(jnp.int32),
        prev_kr=stacked.kr.ravel(),
        prev_plane=stacked.plane.ravel(),
        kr_sum=stacked.kr_sum,
        r_field=flat([p.r_field for p in patterns]),
        rm_field=flat([p.rm_field for p in patterns]),
        prev_selected=stacked.selected,
        prev_filled=stacked.filled,
        fine=fine,
        status=jnp.asarray(status, jnp.int32),
        planes=planes,
        grid_cells=C,
        coarse=coarse,
        fine_curr=current_side(curr_n, curr_valid, config),
        fine_back=back_side(curr_n, curr_valid, config, planes, d, fine.noise),
    )
