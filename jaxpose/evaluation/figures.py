"""The paper's Figures 4–6 as PNG (matplotlib, no display needed).

- Fig. 4: a cloud in two views (along the optical axis z_c, and oblique), frame c, metres.
- Fig. 5: the previous cloud's points selected by each cutting plane, frame n, metres.
- Fig. 6: the intersection patterns before (p = 0) and after the search: circles for the
  previous pattern's filled cells, crosses for the current one's, per plane, in cells.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; never needs a display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from jaxtyping import Array, ArrayLike, Float  # noqa: E402

from .._cloud import Cloud  # noqa: E402
from .._objective import to_moved_frame  # noqa: E402
from .._problem import Problem, round_half_up  # noqa: E402

PLANE_COLOURS = ("tab:red", "tab:green", "tab:blue")


def save_figure(fig, path: Path, dpi: int = 120, title: str | None = None) -> None:
    """Lay out, write a PNG and free the figure (every plot of jaxpose ends here)."""
    if title is not None:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def previous_cells(problem: Problem, plane: int) -> np.ndarray:
    """Filled cells (a, b) of the previous pattern on `plane`, `(K, 2)` grid indices."""
    cells = np.asarray(problem.prev_cells)
    keep = (np.asarray(problem.prev_kr) > 0) & (np.asarray(problem.prev_plane) == plane)
    local = cells[keep] - plane * problem.block
    stride = problem.grid_cells + 2
    return np.stack([local // stride - 1, local % stride - 1], axis=1)


def current_cells(p: Float[ArrayLike, "6"], problem: Problem, plane: int) -> np.ndarray:
    """Filled cells (a, b) of the current pattern on `plane` for displacement p (frame n;
    radians, metres), with the hard objective's rules (|h| ≤ d, round half up, inside the grid)."""
    h, a, b = problem.plane_coords(to_moved_frame(p, problem), plane)
    a, b = round_half_up(a), round_half_up(b)
    inside = np.asarray(problem.curr_valid & (abs(h) <= problem.d) & problem.in_grid(plane, a, b))
    return np.unique(np.stack([np.asarray(a)[inside], np.asarray(b)[inside]], axis=1), axis=0)


def plot_clouds(clouds: dict[str, Cloud], path: Path) -> None:
    """Fig. 4: each cloud viewed along z_c (x right, y down) and from an oblique direction."""
    fig = plt.figure(figsize=(10, 4.8))
    ax_front = fig.add_subplot(1, 2, 1)
    ax_3d = fig.add_subplot(1, 2, 2, projection="3d")
    for (name, cloud), colour in zip(clouds.items(), ("tab:blue", "tab:orange"), strict=False):
        pts = np.asarray(cloud.compact())
        ax_front.scatter(pts[:, 0], pts[:, 1], s=0.5, c=colour, label=f"{name} ({len(pts)} points)")
        ax_3d.scatter(pts[:, 0], pts[:, 2], -pts[:, 1], s=0.3, c=colour)
    ax_front.set(xlabel="x_c, m", ylabel="y_c, m", title="view along z_c", aspect="equal")
    ax_front.invert_yaxis()
    ax_front.legend(markerscale=10, loc="upper right", fontsize=8)
    ax_3d.set(xlabel="x_c, m", ylabel="z_c, m", zlabel="−y_c, m", title="oblique view")
    ax_3d.view_init(elev=25, azim=-60)
    save_figure(fig, path)


def plot_selected(cloud: Cloud, problem: Problem, path: Path) -> None:
    """Fig. 5: the previous cloud in frame n, with the points within d of each plane coloured."""
    b = np.asarray(problem.frame.to_frame(cloud.points))[np.asarray(cloud.valid)]  # frame n
    d = float(problem.d)
    fig = plt.figure(figsize=(11, 4))
    for i, (j, offset) in enumerate(problem.planes[:3]):
        ax = fig.add_subplot(1, 3, i + 1, projection="3d")
        near = np.abs(b[:, j] - offset * d) <= d
        ax.scatter(*b[~near].T, s=0.2, c="0.8")
        ax.scatter(*b[near].T, s=1.5, c=PLANE_COLOURS[i])
        ax.set(title=f"plane {i + 1} (normal n{j + 1}): {near.sum()} points", xlabel="n1", ylabel="n2", zlabel="n3")
        ax.view_init(elev=20, azim=-50)
    save_figure(fig, path)


def plot_patterns(problem: Problem, found: Float[Array, "6"], path: Path, title: str = "") -> None:
    """Fig. 6: per plane, previous filled cells (circles) and current filled cells (crosses)
    at p = 0 (top row) and at the found p (bottom row), in grid cells."""
    nplanes = min(problem.num_planes, 3)
    fig, axes = plt.subplots(2, nplanes, figsize=(4 * nplanes, 8), squeeze=False)
    for row, (label, p) in enumerate((("p = 0", np.zeros(6)), ("found p", np.asarray(found)))):
        for i in range(nplanes):
            ax = axes[row, i]
            prev, curr = previous_cells(problem, i), current_cells(p, problem, i)
            ax.scatter(prev[:, 1], prev[:, 0], s=14, facecolors="none", edgecolors="tab:blue", label="previous")
            ax.scatter(curr[:, 1], curr[:, 0], s=14, marker="x", c="tab:red", linewidths=0.8, label="current")
            ax.set(title=f"plane {i + 1}, {label}", xlabel="ζ cell", ylabel="η cell", aspect="equal")
            ax.legend(fontsize=7, loc="upper right")
    save_figure(fig, path, dpi=110, title=title)


__all__ = ["current_cells", "plot_clouds", "plot_patterns", "plot_selected", "previous_cells", "save_figure"]
