"""Each pair's end-to-end estimate beside the fine objective's own minimum, and GICP's.

`uv run --extra peers python experiments/fine_minimum.py [--pairs 4] [--seed 0] [--levels 0.5]
[--smooth-current off|faces|all] [--plane-source selected|all|all_centroids]`

For `--pairs` pairs per target and noise level of the realistic benchmark
(`jaxpose.evaluation.realistic.make_cases`), prints one line per pair: the rotation (°) and
centroid (cm) errors and the status of the whole default call (`_build_and_estimate`, one
compiled program for all pairs, as `fine_variants.py` runs it), then of the fine stage alone
started from the true motion (`fine_refine`: the minimum the objective itself holds near the
truth), then of small_gicp's GICP on the same clouds. Where the first two agree, the search,
refine and fine stage reached the objective's minimum and only a better objective can do
better; where they differ, the call stopped elsewhere (a slide, another basin). Printed, not
committed (docs, Findings: where the errors at 0.5 cm of noise come from).

`--smooth-current faces` runs both with `FineStage(smooth_current=True)`, `all` also with
every current point that has a plane smoothed (`_fine.SMOOTHED_FRACTION` = 1; docs,
Findings: a smoothed current side). `--plane-source` sets `FineStage.plane_source` in both
(docs, Findings: planes among every previous point). Ends with the median errors per noise level.
"""

from __future__ import annotations

import argparse
import statistics

from fine_variants import benchmark_cases, fine_config, jaxpose_rows, truth_rows

import jaxpose as jp
from jaxpose import _fine


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--levels", default="0.5")
    parser.add_argument("--smooth-current", default="off", choices=("off", "faces", "all"))
    parser.add_argument("--plane-source", default="selected", choices=("selected", "all", "all_centroids"))
    args = parser.parse_args()
    levels, cases, gicp = benchmark_cases(args)
    config = jp.Config()
    if args.smooth_current != "off":
        config = fine_config(config, smooth_current=True)
    if args.plane_source != "selected":
        config = fine_config(config, plane_source=args.plane_source)
    if args.smooth_current == "all":
        _fine.SMOOTHED_FRACTION = 1.0
    whole, _ = jaxpose_rows(cases, config)
    minimum, _ = truth_rows(cases, config)
    print("pair: whole call rotation °, centroid cm, status | from the truth | GICP")
    for case, a, b, g in zip(cases, whole, minimum, gicp, strict=True):
        print(
            f"{case.label:24s} {a['rotation_error_deg']:.4f} {a['centroid_error_cm']:.4f} status {a['status']} | "
            f"{b['rotation_error_deg']:.4f} {b['centroid_error_cm']:.4f} | "
            f"{g['rotation_error_deg']:.4f} {g['centroid_error_cm']:.4f}",
            flush=True,
        )
    for sigma in levels:
        idx = [i for i, c in enumerate(cases) if c.sigma_cm == sigma]
        medians = [
            " / ".join(
                f"{statistics.median(rows[i][key] for i in idx):.4f}"
                for key in ("rotation_error_deg", "centroid_error_cm")
            )
            for rows in (whole, minimum, gicp)
        ]
        print(
            f"σ {sigma} cm medians, rotation ° / centroid cm: whole {medians[0]} | truth {medians[1]} "
            f"| GICP {medians[2]}"
        )


if __name__ == "__main__":
    main()
