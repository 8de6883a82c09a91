"""The realistic benchmark with the previous side's planes fitted among every previous point.

`uv run --extra peers python experiments/realistic_planes.py --plane-source all|all_centroids
[--pairs 8] [--seed 0] [--out results]` → `OUT/realistic_planes_SOURCE.{md,json}`

The pairs, peers, keys and tables of `jaxpose benchmark` (`jaxpose.evaluation.realistic`),
with jaxpose's default config but `FineStage.plane_source` set to SOURCE: "all" fits each
selected previous point's plane to its nearest points among every previous point, "all_centroids"
keeps the selection's normal and takes only the centroid there. Compare with the committed
`results/realistic.json` of the default ("selected") pair by pair. Times are those of this
run's machine; GICP runs in the same run so that the ratio can be compared (docs, Findings:
planes among every previous point).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fine_variants import fine_config

import jaxpose as jp
from jaxpose.evaluation.bench import machine
from jaxpose.evaluation.realistic import available_peers, make_cases, run_jaxpose, run_peer, write_report


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plane-source", required=True, choices=("selected", "all", "all_centroids"))
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    config = fine_config(jp.Config(), plane_source=args.plane_source)
    cases = make_cases(args.pairs, args.seed)
    rows, first_calls = run_jaxpose(cases, config, seed=args.seed)
    peers, missing = available_peers()
    for name, align in peers.items():
        rows += run_peer(name, align, cases)
    stem = args.out / f"realistic_planes_{args.plane_source}"
    header = f"jaxpose config: default with FineStage.plane_source={args.plane_source!r}; "
    header += f"{len(cases)} pairs, seed {args.seed}."
    head = {"machine": machine(), "pairs": len(cases), "seed": args.seed, "plane_source": args.plane_source}
    print(write_report(stem, header, rows, first_calls, missing, head))
    print(f"wrote {stem}.md and .json")


if __name__ == "__main__":
    main()
