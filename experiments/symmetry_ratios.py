"""How nearly axisymmetric the realistic benchmark's previous clouds are: where
`FineStage.symmetry_ratio` comes from.

`uv run python experiments/symmetry_ratios.py [--seeds 0 1 2 3] [--pairs 8]`  (printed)

For each draw of the realistic generator (`jaxpose.evaluation.realistic.make_cases`, every
built-in target, σ = 0, 0.5, 1 and 2 cm, `--pairs` pairs each) and each target, the ratio
that `jaxpose._estimate.symmetry_turns` compares with `FineStage.symmetry_ratio`: the larger
of (second / largest) and (smallest / second) principal moment of the previous cloud
(`jp.plane_frame(prev).inertia`). A view at or above the threshold gets the fine stage's
two runs turned about its near-symmetry axis. Printed per draw and target: how many views
fall in each band, and the smallest ratio.
"""

from __future__ import annotations

import argparse

import numpy as np

import jaxpose as jp
from jaxpose import targets
from jaxpose.evaluation import realistic

BANDS = (0.75, 0.80, 0.82, 0.85)


def view_ratio(cloud: jp.Cloud) -> float:
    """The previous cloud's near-symmetry ratio, as `symmetry_turns` reads its moments."""
    m = np.asarray(jp.plane_frame(cloud).inertia)
    return float(max(m[1] / m[0], m[2] / m[1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--pairs", type=int, default=8)
    args = parser.parse_args()
    heads = [f"< {BANDS[0]}"] + [f"{a}–{b}" for a, b in zip(BANDS[:-1], BANDS[1:], strict=True)] + [f"≥ {BANDS[-1]}"]
    print("| seed | target | views | " + " | ".join(heads) + " | smallest |")
    print("|---" * (len(heads) + 4) + "|")
    for seed in args.seeds:
        for name in targets.BUILT_IN:
            ratios = np.array([view_ratio(c.prev) for c in realistic.make_cases(args.pairs, seed=seed, names=(name,))])
            counts = np.histogram(ratios, bins=(0.0, *BANDS, 1.0 + 1e-9))[0]
            print(f"| {seed} | {name} | {ratios.size} | " + " | ".join(map(str, counts)) + f" | {ratios.min():.3f} |")


if __name__ == "__main__":
    main()
