"""The paper's test example as tables (the report boundary: degrees and centimetres here)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._objective import hard_score, soft_score
from .._poses import true_displacement
from .._problem import Problem
from ..sim._camera import Camera
from ..sim._scenarios import PAPER_POSES, paper_pair, paper_pose
from ..sim._simulate import simulate
from ..sim.targets import n1, n5

PAPER_CLOUD_SIZES = {("N5", "previous"): 4219, ("N5", "variant 2"): 4694}
PAPER_N5_PATTERNS = {"selected": (273, 239, 85), "filled": (169, 116, 64), "f_zero": 0.17, "f_truth": 0.87}


def cloud_statistics(camera: Camera | None = None) -> list[dict]:
    """Valid points, centroid (m, frame c) and extent (m) of the simulated clouds of N1, N5."""
    camera = Camera.camcube2() if camera is None else camera
    rows = []
    for shape, target in (("N1", n1()), ("N5", n5())):
        for pose in PAPER_POSES:
            pts = simulate(camera, target, *paper_pose(pose)).compact()
            rows.append(
                {
                    "shape": shape,
                    "pose": pose,
                    "points": len(pts),
                    "paper": PAPER_CLOUD_SIZES.get((shape, pose)),
                    "centroid": pts.mean(0),
                    "extent": pts.max(0) - pts.min(0),
                }
            )
    return rows


def n5_patterns(camera: Camera | None = None) -> dict:
    """Selected points and filled cells per plane of the N5 previous cloud, and f (hard and
    soft) at zero displacement and at the truth, for the pair previous → variant 2."""
    camera = Camera.camcube2() if camera is None else camera
    pair = paper_pair("N5", "variant 2", camera)
    problem = Problem.build(pair.prev, pair.curr)
    truth = true_displacement(problem.frame, pair.R1, pair.t1, pair.R2, pair.t2)
    zero = jnp.zeros(6)
    return {
        "selected": tuple(int(x) for x in problem.prev_selected),
        "filled": tuple(int(x) for x in problem.prev_filled),
        "hard_zero": float(hard_score(zero, problem)),
        "hard_truth": float(hard_score(truth, problem)),
        "soft_zero": float(soft_score(zero, problem)),
        "soft_truth": float(soft_score(truth, problem)),
        "truth": np.concatenate([np.degrees(np.asarray(truth[:3])), 100 * np.asarray(truth[3:])]),
    }


def markdown_tables(stats: list[dict], patterns: dict) -> str:
    out = [
        "| shape | pose | points (ours) | points (paper) | centroid (m, frame c) | extent (m) |",
        "|---|---|---|---|---|---|",
    ]
    for r in stats:
        c, e = r["centroid"], r["extent"]
        out.append(
            f"| {r['shape']} | {r['pose']} | {r['points']} | {r['paper'] or '–'} | "
            f"({c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}) | ({e[0]:.3f}, {e[1]:.3f}, {e[2]:.3f}) |"
        )
    p = PAPER_N5_PATTERNS
    out += [
        "",
        "| N5, previous → variant 2 | plane 1 | plane 2 | plane 3 | f at p = 0 | f at truth |",
        "|---|---|---|---|---|---|",
        "| selected points, paper | {} | {} | {} | {} | {} |".format(*p["selected"], p["f_zero"], p["f_truth"]),
        "| selected points, ours | {} | {} | {} | hard {:.3f}, soft {:.3f} | hard {:.3f}, soft {:.3f} |".format(
            *patterns["selected"],
            patterns["hard_zero"],
            patterns["soft_zero"],
            patterns["hard_truth"],
            patterns["soft_truth"],
        ),
        "| filled cells, paper | {} | {} | {} | | |".format(*p["filled"]),
        "| filled cells, ours | {} | {} | {} | | |".format(*patterns["filled"]),
    ]
    t = patterns["truth"]
    out += ["", "True displacement in our frame n (θ, φ, ψ in °; x, y, z in cm): " + ", ".join(f"{v:.2f}" for v in t)]
    return "\n".join(out)
