"""Warm public calls and GICP on the speed benchmark's pairs alone, for comparing commits.

`public_speed.warm_pairs` (N5, the satellite and the upper stage at σ = 0 and 1 cm; the
warm `jp.estimate` median of `repeats` calls after a first, compiling one; small_gicp's GICP
on the same clouds), without public_speed's cold processes, CLI and batches. To compare a
commit, check it out beside this one and put its package first on the path:

    git worktree add /tmp/base <rev>
    PYTHONPATH=/tmp/base uv run python experiments/warm_calls.py 1 15 base
    uv run python experiments/warm_calls.py 1 15 head
        → results/warm_calls_<label>.json

Run the commits one after the other with nothing else on the machine.
"""

from __future__ import annotations

import sys

import public_speed
from _common import write_json

import jaxpose


def main(pairs: int = 1, repeats: int = 15, label: str = "head") -> None:
    rows = public_speed.warm_pairs(pairs, repeats)
    name = f"warm_calls_{label}.json"
    write_json(name, {"package": jaxpose.__file__, "pairs": pairs, "repeats": repeats, "rows": rows})


if __name__ == "__main__":
    args = sys.argv[1:]
    main(*(int(a) for a in args[:2]), *args[2:3])
