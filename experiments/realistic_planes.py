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
import dataclasses
import json
from pathlib import Path

import jaxpose as jp
from jaxpose.evaluation.bench import machine
from jaxpose.evaluation.realistic import available_peers, make_cases, markdown, run_jaxpose, run_peer, summarise


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plane-source", required=True, choices=("selected", "all", "all_centroids"))
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results"))
    args = parser.parse_args()
    default = jp.Config()
    config = dataclasses.replace(default, fine=dataclasses.replace(default.fine, plane_source=args.plane_source))
    cases = make_cases(args.pairs, args.seed)
    rows, first_calls = run_jaxpose(cases, config, seed=args.seed)
    peers, missing = available_peers()
    for name, align in peers.items():
        rows += run_peer(name, align, cases)
    by_noise, by_target = summarise(rows, ("sigma_cm",)), summarise(rows, ("target", "sigma_cm"))
    text = f"jaxpose config: default with FineStage.plane_source={args.plane_source!r}; {len(cases)} pairs, "
    text += f"seed {args.seed}.\n\n## By noise level\n\n" + markdown(by_noise)
    text += "\n\n## By target and noise level\n\n" + markdown(by_target, ("target", "sigma_cm"))
    firsts = ", ".join(f"{s:.1f} s" for s in first_calls.values())
    text += f"\n\njaxpose first call per capacity bucket (compilation included, not in the times above): {firsts}."
    if missing:
        text += "\n\nNot run here: " + "; ".join(f"{k} ({v})" for k, v in missing.items())
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"realistic_planes_{args.plane_source}"
    stem.with_suffix(".md").write_text(text + "\n")
    payload = {"machine": machine(), "pairs": len(cases), "seed": args.seed, "plane_source": args.plane_source}
    payload |= {"by_noise": by_noise, "by_target": by_target}
    payload |= {"first_calls_s": list(first_calls.values()), "missing": missing, "rows": rows}
    stem.with_suffix(".json").write_text(json.dumps(payload, indent=2, default=float))
    print(f"wrote {stem}.md and .json")


if __name__ == "__main__":
    main()
