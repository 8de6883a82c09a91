"""The capture benchmark's false success on a noise-free satellite (pair 39, a 92° turn, 90–135°
bin): where its score ranks the estimate 180° off above the truth (issue 23).

Draws the pair as `jaxpose.evaluation.capture.make_cases` does, runs `jp.estimate` with
`Config.capture()` (key as in the benchmark) and lists the hypotheses' errors and supports; then
scores the true motion and the estimate with the capture stage's own hypothesis fit
(`_capture._hypothesis_fit`: the wide and the narrow surface fits, support = inlier fraction ×
`consistency`) and with the narrow fit alone, and reports the consistency at each start.

    uv run python experiments/capture_half_turn.py → results/capture_half_turn.{json,md}
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose import _capture as C
from jaxpose._estimate import STATUS_NAME, rotation_between
from jaxpose._fine import fine_refine
from jaxpose._poses import displacement_from_motion
from jaxpose._problem import sized_config
from jaxpose.evaluation import capture as cp
from jaxpose.evaluation.realistic import errors

PAIR = 39
"""The pair's index in the benchmark (its key is fold_in(key(0), PAIR))."""


def main() -> None:
    cases, _ = cp.make_cases(3, keep=lambda name, sigma, b: name == "satellite" and sigma == 0.0 and b == (90.0, 135.0))
    case = cases[0]
    config = sized_config(case.prev.floating(), case.curr.floating(), jp.Config.capture())
    est = jp.estimate(case.prev, case.curr, config, key=jax.random.fold_in(jax.random.key(0), PAIR))
    H = est.hypotheses
    hypotheses = [
        {"score": float(H.score[k]), **errors(case, H.rotation[k], H.translation[k])}
        for k in range(H.score.shape[0])
        if bool(H.distinct[k])
    ]
    problem = jp.Problem.build(case.prev, case.curr, config)
    truth = displacement_from_motion(
        problem.frame.origin, problem.frame.axes, jnp.asarray(case.rotation), jnp.asarray(case.translation)
    ).astype(problem.d.dtype)
    starts = {"truth": truth, "estimate": est.params}
    score = scorer(problem, config)
    rows = [{"start": name, **score(p, truth)} for name, p in starts.items()]
    report = {
        "pair": PAIR,
        "motion_deg": case.motion_deg,
        "shared": case.overlap,
        "status": STATUS_NAME[int(est.status)],
        "estimate": errors(case, est.rotation, est.translation),
        "hypotheses": hypotheses,
        "scored": rows,
    }
    write_json("capture_half_turn.json", report)
    (RESULTS / "capture_half_turn.md").write_text(markdown(report))
    print(markdown(report))


def scorer(problem, config):
    """A function of a start p (frame n) and the truth: the capture stage's support of p after
    its hypothesis fit and after the narrow fit alone, the consistency at p itself, and how far
    the hypothesis fit ends from the truth (degrees)."""
    so3 = config.so3
    prev = C.previous_surface(problem, so3.points)
    curr, curr_grid = C.current_surface(problem, so3.points)
    gate = jnp.asarray(config.fine.inlier, problem.d.dtype)
    views = C.view_maps(problem)
    fit = C._hypothesis_fit(problem, config, prev, curr, curr_grid)
    narrow = C._hypothesis_configs(config)[1]

    def consistency(p):
        return C.consistency(problem, p, prev, curr, curr_grid, gate, views)

    def score(p, truth) -> dict:
        params, support, agree = fit(p[None])
        alone = fine_refine(problem, narrow, p)
        alone_agree = consistency(alone.params)
        return {
            "support": float(support[0]),
            "consistency": float(agree[0]),
            "fit_from_truth_deg": float(np.degrees(rotation_between(params[0], truth))),
            "narrow_support": float(alone.inliers * alone_agree),
            "narrow_inliers": float(alone.inliers),
            "narrow_consistency": float(alone_agree),
            "consistency_at_start": float(consistency(p)),
        }

    return score


def markdown(report: dict) -> str:
    head = (
        f"Capture pair {report['pair']} (satellite, noise-free, {report['motion_deg']:.1f}° turn, shared "
        f"{report['shared']:.2f}): `{report['status']}`, {report['estimate']['rotation_error_deg']:.2f}° / "
        f"{report['estimate']['centroid_error_cm']:.1f} cm off.\n\n"
        "| hypothesis | support | rotation error, ° | centroid error, cm |\n|---|---|---|---|\n"
    )
    lines = [
        f"| {k} | {h['score']:.3f} | {h['rotation_error_deg']:.2f} | {h['centroid_error_cm']:.1f} |"
        for k, h in enumerate(report["hypotheses"])
    ]
    table = (
        "\n\n| start | support (wide + narrow fit) | its end from the truth, ° | narrow fit alone: support = "
        "inliers × consistency | consistency at the start |\n|---|---|---|---|---|\n"
    )
    rows = [
        f"| {r['start']} | {r['support']:.3f} | {r['fit_from_truth_deg']:.2f} | {r['narrow_support']:.3f} = "
        f"{r['narrow_inliers']:.3f} × {r['narrow_consistency']:.3f} | {r['consistency_at_start']:.3f} |"
        for r in report["scored"]
    ]
    return head + "\n".join(lines) + table + "\n".join(rows) + "\n"


if __name__ == "__main__":
    main()
