"""Configuration of the method: a pytree, with the fields that fix array shapes static.

Lengths in metres, angles in radians. Presets: [`Config.paper`][] (the paper's setting:
3 planes, hard objective, ±20°/±0.10 m box), [`Config.accurate`][] (default: a coarse-pattern
search, one frame period of a 25 Hz camera on 2 CPU cores), [`Config.thorough`][] (the search
on the full patterns, ≈ 17× slower), [`Config.wide`][] (capture, ±90°), [`Config.tracking`][]
and [`Config.fast`][] (tests and real-time use).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import equinox as eqx


class Config(eqx.Module):
    """Settings of the plane-pattern method and its search.

    **Patterns** (DECISIONS.md "Patterns and grid"):

    - `d`: selection half-width and cell size, metres (paper: 0.026).
    - `extension`: grid extension on each side as a fraction of the previous pattern's
      extent in cells (paper: 0.2).
    - `slices`: K parallel slices per axis, offsets (k − (K−1)/2)·2d, k = 0…K−1 (static;
      K = 1 is the paper's three planes).
    **Capacities** (static; they fix array shapes). `None`, the default for each, sizes it
    from the clouds at the Python boundary (`jaxpose.problem.sized_config`: the counts and
    the previous patterns, rounded up to a few buckets so that a stream of frames reuses one
    compiled program). Under `jax.jit` a capacity left at None becomes the cloud's row count
    for the points and `JIT_GRID_CELLS` / `JIT_MAX_CELLS` for the patterns; size a config
    for jitted code with [`Config.sized_for`][] instead. A pattern or cloud that overflows a
    capacity under jit is reported in the problem's status, never silently used.

    - `grid_cells`: capacity C of each plane's grid along each axis.
    - `max_points`: capacity for the current cloud's valid points; fewer slots score faster.
    - `max_prev_points`: capacity for the previous cloud's valid points. The previous points
      are compacted to it once; passes over them are then shorter than over the whole frame.
    - `max_cells`: capacity for the filled cells of one previous pattern.

    **Soft objective** (ours):

    - `bin_width`: width w of the soft cell kernel, in cells, 0 < w ≤ 1 (→ 0: hard cells).
    - `select_width`: width of the soft selection edge, as a fraction of d (→ 0: hard slab).

    **Search** (issue 4):

    - `coarse`: the global search scores a second, coarse problem built with cells of
      `coarse`·d (selection half-width too) from `coarse_points` current points thinned evenly
      (static; 1 = search on the full problem, as the paper). Why: an evaluation's work
      scales with the current points scored (≈ 4 800 on the paper's N5 frames against 512)
      and the grid (3 × 130² cells against 3 × 47²), and the coarse problem's wider cells
      widen each basin, so a smaller CMA-ES finds it. The local refine and the fine
      stage then work on the full problem. `experiments/bench_estimate.py` compares the
      default with `thorough()` (the full problem).
    - `coarse_points`: current points of the coarse problem (static).

    - `angle_box`, `shift_box`: half-widths of the search box for each angle (radians) and
      each translation component (metres); paper: 20° and 0.10 m.
    - `global_objective`: "hard" (the paper's) or "soft" — what CMA-ES maximises (static).
    - `population`, `generations`: CMA-ES size (static).
    - `local`: "bfgs", "nelder_mead" or "none" — the optimistix refine on the soft objective
      (static); `local_steps` its step limit (static); `local_tol` its rtol = atol, in the
      refine's units of 1° and 1 cm (static: it is part of the solver). 3e-4 stops BFGS
      within about 0.006° of a resting point; at 1e-5 the kinks of the neighbourhood max
      kept it zig-zagging to the step limit on half the paper's pairs with the same error
      (`experiments/local_tolerance.py`).
    - `recentre`: how many more CMA-ES searches may run, each centred on the previous best,
      while that best lies at the edge of its box (static; 0 = one search, as the paper).
      The result is reported as `AT_BOX_EDGE` if the last search still ends at its edge.
      Under `jax.vmap` a batch runs as many searches as its neediest pair (one
      `lax.while_loop`); set 0 for batched work where that matters.
    - `restarts`: how many more independent CMA-ES searches (each with its own re-centring)
      may run while the best score is below `restart_below`; the best one is kept (static;
      0 = none, the default; `wide()` uses 7). See `jaxpose.search.restarted_search`.
    - `restart_below`: the global objective's value (0–1) at or above which a search is
      trusted and no restart runs.
    - `min_score`: a result whose hard score is below this is reported as low-score. 0.7
      (was 0.5): on the 100-pair capture set the results ≥ 5° off that reported success had
      hard scores 0.54–0.73 (8 of 11 below 0.7) and the correct ones 0.65–0.97 (2 of 74
      below 0.7); with 2 cm range noise correct results scored 0.75–0.79.

    **Fine stage** (ours, `jaxpose.fine`): point-to-plane least squares over the visible
    surface (by default; or on the points near the cutting planes), after the local refine.
    On the realistic benchmark's 28 pairs of `make_cases(1)` (every target, σ 0–2 cm) the
    whole surface with 4096 points a side and centroid anchors found 24 against 18 with
    896 near-plane points (slabs of 3d / 2d, point anchors), with no false success against
    2 (`experiments/realistic_settings.py`; 8192 points did worse, 20 found, not yet
    understood).

    - `fine`: "point_to_plane" or "none" (static).
    - `fine_prev_slab`, `fine_curr_slab`: half-widths of the previous and current slabs
      around each cutting plane, in units of d (the previous one is wider so that every
      current point finds its neighbours); inf (the default): the whole visible surface.
    - `fine_inlier`: current points farther than this from every previous point are left
      out (metres): surface seen in only one cloud.
    - `fine_planar_fraction`: fraction of the previous points kept, the most planar ones
      (smallest / middle scatter eigenvalue of the neighbourhood): edges and corners go.
    - `fine_points`: capacity of each side (static); more points are thinned evenly.
    - `fine_neighbours`: neighbours of a normal fit (static).
    - `fine_anchor`: "centroid" (default) or "point" (static): each previous point's plane
      goes through the point itself or through its neighbourhood's centroid. With 1 cm range
      noise the point anchor biases registrations in proportion to the motion (the nearest
      match favours points that noise moved towards the current point) and the centroid
      removes most of it (`experiments/fine_anchor.py`). Noise-free, the plane of a
      neighbourhood that spans an edge misses the surface by micrometres to millimetres;
      `thorough()` and `wide()` keep the point anchor and the slabs of 3d / 2d.
    - `fine_guard`: the fine stage's result is dropped, and the local refine's kept, when its
      hard score is lower than the refine's by more than this (0–1; 1 = never dropped). On
      a random view of `experiments/bench_estimate.py` (a development run with 1024 points a
      side) the fine stage slid 24 cm along a face, its hard score falling from ≈ 0.9 to 0.6.
      `thorough()`, `wide()` and `tracking()` keep 1, as when their committed results were
      measured.
    - `fine_from_rest`: also run the fine stage from p = 0 (no motion) and keep whichever
      result explains more of the current cloud (`jaxpose.estimate.better_fine`): over the
      small motions between frames the surface fit's own basin often holds the truth where
      the pattern search settled a few degrees off.
    - `fine_rounds`: most match-then-solve rounds (static); `fine_steps`, `fine_tol`: LM's
      step limit per round and rtol = atol in units of 1° / 1 cm (static). 1e-4 (was 1e-6):
      on the paper's pairs × 3 keys every result is within 0.00004° / 0.00004 cm of the
      truth with either, and the fine stage took a median of 14.5 LM steps (at most 29)
      against 35 (48) at 1e-6 (`experiments/local_tolerance.py fine`); its steps were its
      largest cost. `thorough()`, `wide()` and `tracking()` keep 1e-6, as when their
      committed results were measured.

    **Input checks:**

    - `max_range`: clouds with a point farther than this from the camera (metres) are
      refused at the Python boundary (wrong units or garbage, not lidar returns).
    """

    d: float = 0.026
    extension: float = 0.2
    bin_width: float = 1.0
    select_width: float = 0.5
    angle_box: float = math.radians(20.0)
    shift_box: float = 0.10
    min_score: float = 0.7
    max_range: float = 1000.0
    slices: int = eqx.field(static=True, default=1)
    coarse: int = eqx.field(static=True, default=3)
    coarse_points: int = eqx.field(static=True, default=512)
    grid_cells: int | None = eqx.field(static=True, default=None)
    max_points: int | None = eqx.field(static=True, default=None)
    max_prev_points: int | None = eqx.field(static=True, default=None)
    max_cells: int | None = eqx.field(static=True, default=None)
    global_objective: Literal["hard", "soft"] = eqx.field(static=True, default="soft")
    population: int = eqx.field(static=True, default=16)
    generations: int = eqx.field(static=True, default=16)
    local: Literal["bfgs", "nelder_mead", "none"] = eqx.field(static=True, default="bfgs")
    local_steps: int = eqx.field(static=True, default=8)
    local_tol: float = eqx.field(static=True, default=3e-4)
    recentre: int = eqx.field(static=True, default=2)
    restarts: int = eqx.field(static=True, default=0)
    restart_below: float = 0.8
    fine_prev_slab: float = math.inf
    fine_curr_slab: float = math.inf
    fine_inlier: float = 0.03
    fine_planar_fraction: float = 0.7
    fine_guard: float = 0.05
    fine_from_rest: bool = eqx.field(static=True, default=True)
    fine: Literal["point_to_plane", "none"] = eqx.field(static=True, default="point_to_plane")
    fine_points: int = eqx.field(static=True, default=4096)
    fine_neighbours: int = eqx.field(static=True, default=20)
    fine_anchor: Literal["point", "centroid"] = eqx.field(static=True, default="centroid")
    fine_rounds: int = eqx.field(static=True, default=20)
    fine_steps: int = eqx.field(static=True, default=20)
    fine_tol: float = eqx.field(static=True, default=1e-4)

    def __check_init__(self):
        if self.coarse < 1 or self.coarse_points < 10:
            raise ValueError(
                f"Config.coarse must be ≥ 1 and coarse_points ≥ 10, got {self.coarse!r}, {self.coarse_points!r}."
            )
        capacities = (self.grid_cells, self.max_points, self.max_prev_points, self.max_cells)
        if self.slices < 1 or min(c or 3 for c in capacities) < 3:
            raise ValueError("slices must be ≥ 1; grid_cells, max_points, max_prev_points and max_cells ≥ 3 or None.")
        if self.global_objective not in ("hard", "soft"):
            raise ValueError(f"global_objective must be 'hard' or 'soft', got {self.global_objective!r}.")
        if self.local not in ("bfgs", "nelder_mead", "none"):
            raise ValueError(f"local must be 'bfgs', 'nelder_mead' or 'none', got {self.local!r}.")
        if self.population < 2 or self.generations < 1 or self.local_steps < 0 or not self.local_tol > 0:
            raise ValueError("population ≥ 2, generations ≥ 1, local_steps ≥ 0 and local_tol > 0 are required.")
        if self.fine not in ("point_to_plane", "none"):
            raise ValueError(f"fine must be 'point_to_plane' or 'none', got {self.fine!r}.")
        if self.fine_anchor not in ("centroid", "point"):
            raise ValueError(f"fine_anchor must be 'centroid' or 'point', got {self.fine_anchor!r}.")
        counts = (self.fine_points, self.fine_neighbours - 2, self.fine_steps, self.fine_rounds)
        if min(counts) < 1 or not self.fine_tol > 0:
            raise ValueError("fine_points ≥ 1, fine_neighbours ≥ 3, fine_steps ≥ 1 and fine_tol > 0 are required.")
        if self.recentre < 0 or self.restarts < 0:
            raise ValueError(f"Config.recentre and restarts must be ≥ 0, got {self.recentre!r}, {self.restarts!r}.")
        ranges = {
            "d": (self.d, 0.0, math.inf),
            "bin_width": (self.bin_width, 0.0, 1.0),
            "select_width": (self.select_width, 0.0, math.inf),
            "angle_box": (self.angle_box, 0.0, math.pi),
            "shift_box": (self.shift_box, 0.0, math.inf),
            "max_range": (self.max_range, 0.0, math.inf),
            "fine_prev_slab": (self.fine_prev_slab, 0.0, math.inf),
            "fine_curr_slab": (self.fine_curr_slab, 0.0, math.inf),
            "fine_inlier": (self.fine_inlier, 0.0, math.inf),
            "fine_planar_fraction": (self.fine_planar_fraction, 0.0, 1.0),
        }
        for name, (value, lo, hi) in ranges.items():
            if isinstance(value, int | float) and not lo < value <= hi:
                raise ValueError(f"Config.{name} must be in ({lo:g}, {hi:g}], got {value!r} (metres/radians).")
        if isinstance(self.extension, int | float) and not self.extension >= 0:
            raise ValueError(f"Config.extension must be ≥ 0, got {self.extension!r}.")
        for name in ("min_score", "restart_below", "fine_guard"):
            value = getattr(self, name)
            if isinstance(value, int | float) and not 0 <= value <= 1:
                raise ValueError(f"Config.{name} must be in [0, 1], got {value!r}.")

    @property
    def num_planes(self) -> int:
        return 3 * self.slices

    def planes(self) -> tuple[tuple[int, float], ...]:
        """(normal axis j, offset in units of d) of every cutting plane, plane 1 first."""
        K = self.slices
        return tuple((j, 2.0 * (k - (K - 1) / 2)) for j in range(3) for k in range(K))

    def with_jit_capacities(self, prev_rows: int, curr_rows: int) -> Config:
        """This config with each capacity left at None set for traced clouds of `prev_rows` and
        `curr_rows` rows: the row counts for the points, `JIT_GRID_CELLS` and `JIT_MAX_CELLS`."""
        fill = {"max_prev_points": prev_rows, "max_points": curr_rows}
        fill |= {"grid_cells": JIT_GRID_CELLS, "max_cells": JIT_MAX_CELLS}
        return dataclasses.replace(self, **{k: v for k, v in fill.items() if getattr(self, k) is None})

    def sized_for(self, camera, extent: float, distance: float | None = None) -> Config:
        """This config with its capacities sized for a target of largest extent `extent`
        (metres) seen by `camera` at `distance` (metres; default the nearest the target fits
        in the field of view, never below `camera.range_min`): for code that calls
        `estimate` under `jax.jit`, where the clouds cannot size it.

        - points: the pixels the target's bounding sphere can cover at that distance (at most
          the camera's frame);
        - `grid_cells`: (1 + 2·extension)·extent/d + 3 cells plus the margin of `sized_config`;
        - `max_cells`: 4π·extent/d, twice the cells along the outline of a slab through a
          convex body of that size, at least `JIT_MAX_CELLS` / 4.

        Each is rounded up by `jaxpose.problem.bucket`; capacities already set are kept."""
        from .problem import GRID_MARGIN, bucket

        tan_half = min(float(camera.tan_half_x), float(camera.tan_half_y))
        fit = extent / 2 / tan_half
        distance = max(fit, float(camera.range_min)) if distance is None else distance
        radius = extent / 2
        half_angle = math.asin(min(1.0, radius / max(distance, radius)))
        share = min(
            1.0, (math.tan(half_angle) / float(camera.tan_half_x)) * (math.tan(half_angle) / float(camera.tan_half_y))
        )
        frame = camera.width * camera.height
        pixels = min(bucket(math.ceil(share * frame) + 1, 512), frame)  # never more than a frame
        cells = (1 + 2 * self.extension) * extent / self.d + 3 + GRID_MARGIN
        fill = {"max_points": pixels, "max_prev_points": pixels, "grid_cells": bucket(math.ceil(cells), 32)}
        fill["max_cells"] = bucket(max(math.ceil(4 * math.pi * extent / self.d), JIT_MAX_CELLS // 4), 64)
        return dataclasses.replace(self, **{k: v for k, v in fill.items() if getattr(self, k) is None})

    @property
    def coarse_config(self) -> Config:
        """The settings of the coarse problem of the search (see `coarse`): cells and selection
        of `coarse`·d, a grid of ⌈C / coarse⌉ + 2 cells, `coarse_points` current points, no fine
        stage."""
        return dataclasses.replace(
            self,
            d=self.d * self.coarse,
            grid_cells=-(-self.grid_cells // self.coarse) + 2,
            max_points=self.coarse_points,
            fine="none",
            coarse=1,
        )

    @classmethod
    def paper(cls, **kw) -> Config:
        """The paper's setting: three planes, d = 0.026 m, the hard objective, one search in the
        box on the full patterns, no local refine and no fine stage."""
        paper = {"global_objective": "hard", "local": "none", "fine": "none", "recentre": 0, "coarse": 1}
        paper |= {"population": 48, "generations": 60}
        return cls(**{**paper, **kw})

    @classmethod
    def accurate(cls, **kw) -> Config:
        """The default: CMA-ES (16 × 16) on the soft objective of the coarse problem (cells of
        3d, 512 current points), at most 8 BFGS steps on the full soft objective, then the
        fine stage over the whole visible surface (4096 points a side, planes through the
        neighbourhood centroids), from the refine's result and from rest."""
        return cls(**kw)

    @classmethod
    def thorough(cls, **kw) -> Config:
        """The default before the coarse search (kept, and the base of `wide()` and
        `tracking()`): CMA-ES (32 × 40) on the full soft objective, up to 100 BFGS steps,
        2048 fine-stage points a side, no fine guard. About 17× slower than `accurate()`;
        `experiments/bench_estimate.py` compares their accuracy on random views."""
        return cls(**{**THOROUGH, **kw})

    @classmethod
    def wide(cls, **kw) -> Config:
        """Capture mode, for a first estimate with no prior (issue 4's capture test:
        `jaxpose compare --set capture`): a ±90° / ±0.30 m box, a larger CMA-ES, up to 7
        restarts while the best soft score is below 0.8, and three slices per axis (9 planes).

        Why 9 planes: over ±90° the three-plane objective has wrong maxima (a ≈90° turn that
        lines up flat faces, or a few degrees' slide along a symmetric part) that can score
        above the truth; nine planes rank some of them below it (a scratch check, not
        committed), so restarts leave them. With both, the capture set went from 84 to 95
        found of 100 (`jaxpose compare --set capture`, README). 9 planes score three
        times the patterns per evaluation."""
        box = {"angle_box": math.radians(90.0), "shift_box": 0.30, "population": 64, "generations": 60}
        box |= {"restarts": 7, "slices": 3}
        return cls(**{**THOROUGH, **box, **kw})

    @classmethod
    def tracking(cls, **kw) -> Config:
        """For frame-to-frame registration of noisy clouds (`jaxpose.track`): `thorough()`
        with the fine stage on the whole cloud (slabs of infinite width, 6144 points a side)
        instead of the points near the cutting planes. The search still uses the planes.

        Why: with 1 cm range noise the fine stage's error falls as more surface is fitted. On
        the 10 s N5 tumbles of `experiments/tumble_tracking.py` (4.5 °/s, 5.5 m) 245 and 241
        of 251 frames succeeded against 210 and 220 with `thorough()`, then the default (the
        hard score at a better pose is higher), and on seed 0 the registration error's median
        was 0.067° against 0.141° (fine planes through the points, as then). Since, the
        planes go through the neighbourhood centroids (`fine_anchor`), which removed a bias
        of the registrations that grew with the motion: 247–250 of 251 frames of six seeds
        succeeded, with medians 0.043–0.062°. It is slower per pair (neighbour search over 6144 points; not
        benchmarked alone). The search is `thorough()`'s, and so is the capture range.
        """
        whole = {"fine_prev_slab": math.inf, "fine_curr_slab": math.inf, "fine_points": 6144, "fine_anchor": "centroid"}
        return cls(**{**THOROUGH, **whole, **kw})

    @classmethod
    def fast(cls, **kw) -> Config:
        """The default's search with the fine stage on the points near the cutting planes (896
        a side, slabs of 3d / 2d, planes through the points): several times cheaper than the
        whole surface, and exact on noise-free pairs of flat faces; less accurate under
        range noise (`Config`'s fine-stage notes). The tests run it on the paper's pairs."""
        near_planes = {"fine_prev_slab": 3.0, "fine_curr_slab": 2.0, "fine_points": 896, "fine_anchor": "point"}
        return cls(**{**near_planes, **kw})


JIT_GRID_CELLS = 256
"""`grid_cells` under jit when the config leaves it at None: with the default d and
extension, patterns up to about 4.7 m across."""

JIT_MAX_CELLS = 2048
"""`max_cells` under jit when the config leaves it at None."""

THOROUGH = {
    "coarse": 1,
    "population": 32,
    "generations": 40,
    "local_steps": 100,
    "fine_points": 2048,
    "fine_prev_slab": 3.0,
    "fine_curr_slab": 2.0,
    "fine_anchor": "point",
    "fine_guard": 1.0,
    "fine_tol": 1e-6,
}
"""The settings of [`Config.thorough`][] that differ from the default."""
