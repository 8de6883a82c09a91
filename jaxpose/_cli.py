"""The `jaxpose` command line (typer). Degrees and centimetres at this boundary only."""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Annotated

try:
    import typer
except ImportError as err:  # the library installs without the command line's dependencies
    raise SystemExit("the jaxpose command line needs the cli extra: pip install 'jaxpose[cli]'") from err

app = typer.Typer(help="jaxpose: pose change of an unknown-shape target from two lidar clouds.", no_args_is_help=True)


@app.command()
def paper(out: Annotated[Path, typer.Option(help="Folder for the Markdown table.")] = Path("results")):
    """The paper's test example: simulated cloud statistics and N5 intersection patterns."""
    from rich.console import Console
    from rich.markdown import Markdown

    from .evaluation.report import cloud_statistics, markdown_tables, n5_patterns

    text = markdown_tables(cloud_statistics(), n5_patterns())
    Console().print(Markdown(text))
    out.mkdir(parents=True, exist_ok=True)
    (out / "paper_patterns.md").write_text(text + "\n")
    typer.echo(f"wrote {out / 'paper_patterns.md'}")


def _progress():
    """A rich progress bar for long loops (a bar, counts, elapsed and remaining time)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn()
    )


@app.command()
def reproduce(
    out: Annotated[Path, typer.Option(help="Folder for tables (Markdown, CSV) and figures (PNG).")] = Path("results"),
    seed: Annotated[int, typer.Option(help="PRNG seed of the searches.")] = 0,
    quick: Annotated[bool, typer.Option(help="Small searches (for CI and notebooks), not the real settings.")] = False,
):
    """The paper's test example end to end: Tables 1–3 and Figs. 4–6, the paper's configuration
    (3 planes, hard objective, no refine) and ours (default), beside the paper's printed values."""
    import dataclasses

    from rich.console import Console
    from rich.markdown import Markdown

    from . import Capacities, Config
    from .evaluation.figures import plot_clouds, plot_patterns, plot_selected
    from .evaluation.reproduction import run_reproduction, tables_markdown, write_csv
    from .sim._scenarios import paper_pair

    _enable_compile_cache()
    # One capacity for all four pairs (one compile per config); --quick swaps in small searches.
    capacities = Capacities(max_points=5120)
    if quick:
        small = dataclasses.replace(Config.paper().search, population=16, generations=20)
        configs = {
            "paper": Config.paper(search=small, capacities=capacities),
            "default": Config.fast(capacities=capacities),
        }
    else:
        configs = {"paper": Config.paper(capacities=capacities), "default": Config(capacities=capacities)}
    out.mkdir(parents=True, exist_ok=True)
    with _progress() as bar:
        task = bar.add_task("estimating the paper's pairs", total=4 * len(configs))
        results = run_reproduction(configs, seed, progress=lambda _: bar.advance(task))
    text = tables_markdown(results)
    if quick:
        text = "**Quick run (small searches): not the published settings.**\n\n" + text
    Console().print(Markdown(text))
    (out / "reproduction.md").write_text(text + "\n")
    write_csv(results, out / "reproduction.csv")
    n5 = paper_pair("N5", "variant 2")
    plot_clouds({"N5 previous": n5.prev, "N5 variant 2": n5.curr}, out / "fig4_clouds.png")
    for name, rows in results.items():
        r = next(r for r in rows if r["shape"] == "N5" and r["variant"] == "variant 2")
        if name == "default":
            plot_selected(n5.prev, r["problem"], out / "fig5_selected.png")
        title = f"N5 variant 2, {name} config: hard f {r['hard']:.2f} at the found p"
        plot_patterns(r["problem"], r["estimate"].params, out / f"fig6_patterns_{name}.png", title)
    typer.echo(
        f"wrote {out}/: reproduction.md, reproduction.csv, fig4_clouds.png, fig5_selected.png, fig6_patterns_*.png"
    )


@app.command()
def sweep(
    axes: Annotated[str, typer.Option(help="Comma-separated: rotation, noise, distance, dropout.")] = (
        "rotation,noise,distance,dropout"
    ),
    trials: Annotated[int, typer.Option(help="Random pairs per value.")] = 10,
    preset: Annotated[
        str,
        typer.Option(help="Config preset: default (also called accurate), fast, wide, capture, tracking or paper."),
    ] = "default",
    seed: Annotated[int, typer.Option(help="PRNG seed of the pairs and the search.")] = 0,
    out: Annotated[Path, typer.Option(help="Folder for sweep_<preset>.{json,png}.")] = Path("results"),
    distributed: Annotated[
        bool, typer.Option(help="Join a multi-host run first (jax.distributed.initialize(); cluster from env).")
    ] = False,
):
    """Monte Carlo error and success rate against rotation magnitude (0.5–60°), range noise σ
    (0–2 cm), distance (1–7 m) and pixel dropout, one condition at a time, with plots. Each
    value's trials run as one batch sharded over all devices (all hosts with --distributed;
    process 0 writes the files)."""
    import json

    import jax

    if distributed:
        jax.distributed.initialize()

    from .evaluation.bench import machine
    from .evaluation.sweep import AXES, BASE, plot_sweep, run_sweep

    names = [a.strip() for a in axes.split(",") if a.strip()]
    if bad := [a for a in names if a not in AXES]:
        raise typer.BadParameter(f"unknown axes {bad}; choose from {', '.join(AXES)}.")
    _enable_compile_cache()
    config = _preset(preset)
    with _progress() as bar:
        task = bar.add_task(f"sweep ({preset}, {trials} trials per value)", total=sum(len(AXES[a][1]) for a in names))
        results = run_sweep(names, trials, config, seed, progress=lambda: bar.advance(task))
    for axis, rows in results.items():
        typer.echo(f"{AXES[axis][0]}:")
        for r in rows:
            med = r.get("median_rotation_error_deg", float("nan"))
            typer.echo(
                f"  {r['value']:6g}  found {r['found']}/{r['trials']}  success {r['success']}  "
                f"false success {r['false_success']}  unusable {r['unusable']}  median rot. error {med:.3f}°"
            )
    if jax.process_index() != 0:
        return
    out.mkdir(parents=True, exist_ok=True)
    plot_sweep(results, out / f"sweep_{preset}.png", f"jaxpose {preset}, N5, {trials} trials per value, base {BASE}")
    payload = {"machine": machine(), "preset": preset, "trials": trials, "base": BASE, "results": results}
    (out / f"sweep_{preset}.json").write_text(json.dumps(payload, indent=2))
    typer.echo(f"wrote {out / f'sweep_{preset}.json'} and .png")


PAIR_SETS = ("paper", "capture")


@app.command()
def compare(
    pair_set: Annotated[
        str, typer.Option("--set", help="paper (the four pairs) or capture (random, 5–45°).")
    ] = "paper",
    pairs: Annotated[int, typer.Option(help="Number of capture pairs.")] = 100,
    preset: Annotated[str, typer.Option(help="jaxpose preset (default: default for paper, wide for capture).")] = "",
    seed: Annotated[int, typer.Option(help="PRNG seed of jaxpose's search.")] = 0,
    out: Annotated[Path, typer.Option(help="Folder for compare_<set>.{md,json}.")] = Path("results"),
):
    """jaxpose and the peers (small_gicp ICP / plane-ICP / GICP; Open3D ICPs, FGR, RANSAC when
    installed: `pip install 'jaxpose[peers]'`) on the same pairs, errors and times in one table."""
    import json

    import numpy as np

    from ._rotations import rotation_angle
    from .evaluation.bench import machine
    from .evaluation.comparison import markdown_summary, run_jaxpose, run_peer, summarise
    from .evaluation.peers import available_peers
    from .sim._scenarios import capture_pairs, paper_pairs

    if pair_set not in PAIR_SETS:
        raise typer.BadParameter(f"unknown set {pair_set!r}; choose one of {', '.join(PAIR_SETS)}.")
    _enable_compile_cache()
    preset = preset or ("default" if pair_set == "paper" else "wide")
    config = _preset(preset)  # capacities sized from all the pairs (run_jaxpose)
    chosen = paper_pairs() if pair_set == "paper" else capture_pairs(pairs, seed=seed)
    peers, missing = available_peers()
    with _progress() as bar:
        task = bar.add_task(f"jaxpose ({preset})", total=len(chosen))
        repeats = 5 if pair_set == "paper" else 1
        rows, compile_s = run_jaxpose(chosen, config, seed, lambda: bar.advance(task), repeats)
        for name, align in peers.items():
            task = bar.add_task(name, total=len(chosen))
            rows += run_peer(name, align, chosen, progress=lambda t=task: bar.advance(t))
    angles = {p.label: float(np.degrees(rotation_angle(p.motion[0], np.eye(3)))) for p in chosen}
    bins = ((5, 15), (15, 25), (25, 35), (35, 45)) if pair_set == "capture" else None
    summary = summarise(rows, angles, bins)
    text = markdown_summary(summary, compile_s)
    if missing:
        text += "\n\nNot run here: " + "; ".join(f"{k} ({v})" for k, v in missing.items())
    typer.echo(text)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"compare_{pair_set}.md").write_text(text + "\n")
    payload = {"machine": machine(), "preset": preset, "summary": summary, "compile_s": compile_s, "rows": rows}
    (out / f"compare_{pair_set}.json").write_text(json.dumps({**payload, "missing": missing}, indent=2))
    typer.echo(f"wrote {out / f'compare_{pair_set}.md'} and .json")


@app.command()
def benchmark(
    pairs: Annotated[int, typer.Option(help="Pairs per target and noise level (7 targets × 4 levels).")] = 8,
    seed: Annotated[int, typer.Option(help="Seed of the poses, motions and sensor noise.")] = 0,
    out: Annotated[Path, typer.Option(help="Folder for realistic.{md,json,png}.")] = Path("results"),
    preset: Annotated[str, typer.Option(help="jaxpose's config: default, or a Config preset's name.")] = "default",
):
    """The realistic benchmark: every built-in target, random views and motions of 1–15°,
    2–6.5 m, ToF range noise 0–2 cm, dropout, flying pixels; jaxpose's public `estimate`
    against small_gicp GICP and Open3D point-to-plane ICP on the same clouds."""
    from .evaluation.bench import machine
    from .evaluation.realistic import available_peers, make_cases, run_jaxpose, run_peer, write_report

    _enable_compile_cache()
    typer.echo("simulating the pairs …")
    cases = make_cases(pairs, seed)
    peers, missing = available_peers()
    with _progress() as bar:
        task = bar.add_task("jaxpose", total=len(cases))
        config = None if preset == "default" else _preset(preset)
        rows, first_calls = run_jaxpose(cases, config, seed=seed, progress=lambda: bar.advance(task))
        for name, align in peers.items():
            task = bar.add_task(name, total=len(cases))
            rows += run_peer(name, align, cases, progress=lambda t=task: bar.advance(t))
    header = f"jaxpose config: {preset}; {len(cases)} pairs, seed {seed}."
    head = {"machine": machine(), "pairs": len(cases), "seed": seed, "preset": preset}
    typer.echo(write_report(out / "realistic", header, rows, first_calls, missing, head, with_plot=True))
    typer.echo(f"wrote {out / 'realistic.md'}, .json and .png")


@app.command()
def bench(
    out: Annotated[Path, typer.Option(help="JSON file to write.")] = Path("results/bench.json"),
    repeats: Annotated[int, typer.Option(help="Timed repeats after the first (compile) call.")] = 10,
):
    """Simulator time, scoring throughput, estimate time per pair and per vmapped batch, and the
    compile times, on the paper's N5 pair → JSON (median of repeats, compile separately)."""
    import json

    from .evaluation.bench import run_bench

    with _progress() as bar:
        task = bar.add_task("benchmarking (compiles included)", total=None)
        result = run_bench(repeats=repeats)
        bar.update(task, total=1, completed=1)
    for name, r in result.items():
        if isinstance(r, dict) and "median_s" in r:
            rate = next((f"  {r[k]:.1f} {k}" for k in ("poses_per_s", "pairs_per_s") if k in r), "")
            typer.echo(f"{name:28s} {1e3 * r['median_s']:9.2f} ms  (compile {r['compile_s']:.1f} s){rate}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    typer.echo(f"wrote {out}")


def _preset(name: str, **capacities: int):
    """The named Config preset ("default" or its older name "accurate", "fast", "paper", "wide",
    "capture", "tracking") with the given capacities (those not given are sized from the data)."""
    from . import Capacities, Config

    presets = {
        "default": Config,
        "accurate": Config,
        "fast": Config.fast,
        "paper": Config.paper,
        "wide": Config.wide,
        "capture": Config.capture,
        "tracking": Config.tracking,
    }
    if name not in presets:
        raise typer.BadParameter(f"unknown preset {name!r}; choose one of {', '.join(presets)}.")
    return presets[name](capacities=Capacities(**capacities))


def _standard_deviations(covariance) -> dict | None:
    """The largest predicted 1σ of the rotation (degrees) and the translation (centimetres)
    of `Estimate.covariance` (camera frame), or None without a usable one."""
    import numpy as np

    if covariance is None:
        return None
    cov = np.asarray(covariance, float)
    largest = lambda block: float(np.sqrt(max(np.linalg.eigvalsh(block)[-1], 0.0)))  # noqa: E731
    if not np.all(np.isfinite(cov)):
        return None
    return {"rotation_deg": float(np.degrees(largest(cov[:3, :3]))), "translation_cm": 100 * largest(cov[3:, 3:])}


@functools.cache
def _compiled_angles():
    """`jaxpose.angles` as one compiled program (a `BoundedJit`, so on disk with the compile
    cache), made on first use: the CLI imports JAX only when a command runs."""
    from ._programs import BoundedJit
    from ._rotations import angles

    return BoundedJit(angles)


def _enable_compile_cache() -> None:
    """Keep compiled programs across CLI runs, jaxpose's and the rest of JAX's
    (`jaxpose.enable_compile_cache`; `JAXPOSE_CACHE=off` keeps none). Imported here, not at the
    top, so that the CLI's help does not import JAX."""
    from ._programs import enable_compile_cache

    enable_compile_cache()


@app.command()
def estimate(
    prev: Annotated[Path, typer.Argument(help="Previous cloud (PLY, PCD, NPY, NPZ or CSV; camera frame, metres).")],
    curr: Annotated[Path, typer.Argument(help="Current cloud, same formats.")],
    preset: Annotated[
        str,
        typer.Option(help="Config preset: default (also called accurate), fast, wide, capture, tracking or paper."),
    ] = "default",
    seed: Annotated[int, typer.Option(help="PRNG seed of the global search.")] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object instead of a table.")] = False,
):
    """Displacement of the target between two cloud files, with its status.

    Prints p in the plane frame n (degrees, cm) and the motion x ↦ R x + t in the camera frame
    (R as angles in degrees, t in cm), and any other distinct hypothesis (`--preset capture`).
    Exit code 0 on success, 1 for any other status, 2 for unreadable or unusable input.
    """
    import json

    import jax
    import numpy as np

    from . import estimate as run_estimate
    from ._estimate import STATUS_TEXT
    from ._io import load_cloud

    config = _preset(preset)
    _enable_compile_cache()
    try:
        result = run_estimate(load_cloud(prev), load_cloud(curr), config, key=jax.random.key(seed))
    except (ValueError, FileNotFoundError) as err:
        typer.echo(f"error: {err}", err=True)
        raise typer.Exit(2) from err
    p = np.asarray(result.params, float)
    # The estimate's angles and its hypotheses' in one compiled call (op-by-op dispatch of
    # `angles` costs a fresh process about 0.4 s).
    rotations = np.concatenate([np.asarray(result.rotation)[None], np.asarray(result.hypotheses.rotation)])
    angles_deg = np.degrees(np.asarray(_compiled_angles()(rotations), float))
    out = {
        "status": int(result.status),
        "status_text": STATUS_TEXT[int(result.status)],
        "frame_n": {"angles_deg": np.degrees(p[:3]).tolist(), "translation_cm": (100 * p[3:]).tolist()},
        "camera_frame": {
            "rotation_angles_deg": angles_deg[0].tolist(),
            "rotation_matrix": np.asarray(result.rotation, float).tolist(),
            "translation_cm": (100 * np.asarray(result.translation, float)).tolist(),
        },
        "hard_score": float(result.hard),
        "soft_score": float(result.soft),
        "ambiguous": bool(result.ambiguous),
        "std": _standard_deviations(result.covariance),
        "spread_deg": math.degrees(float(result.spread)),
        "residual_scale_cm": None if result.residual_scale is None else 100 * float(result.residual_scale),
        "hypotheses": [
            {
                "rotation_angles_deg": deg.tolist(),
                "translation_cm": (100 * np.asarray(t, float)).tolist(),
                "score": float(score),
            }
            for deg, t, score, distinct in zip(
                angles_deg[1:],
                result.hypotheses.translation,
                result.hypotheses.score,
                result.hypotheses.distinct,
                strict=True,
            )
            if bool(distinct)
        ],
    }
    if as_json:
        typer.echo(json.dumps(out, indent=2))
    else:
        fmt = lambda xs: "  ".join(f"{x:9.4f}" for x in xs)  # noqa: E731
        typer.echo(f"status            {out['status']} ({out['status_text']})")
        typer.echo(f"frame n  θ φ ψ °  {fmt(out['frame_n']['angles_deg'])}")
        typer.echo(f"frame n  x y z cm {fmt(out['frame_n']['translation_cm'])}")
        typer.echo(f"camera   θ φ ψ °  {fmt(out['camera_frame']['rotation_angles_deg'])}")
        typer.echo(f"camera   t cm     {fmt(out['camera_frame']['translation_cm'])}")
        typer.echo(f"hard f {out['hard_score']:.4f}   soft f {out['soft_score']:.4f}")
        if out["std"] is not None:
            std = out["std"]
            typer.echo(f"1σ camera         {std['rotation_deg']:9.4f} °  {std['translation_cm']:9.4f} cm")
            typer.echo(f"residual scale σ̂  {out['residual_scale_cm']:9.4f} cm")
        if out["spread_deg"] > 0:
            typer.echo(f"spread of equally good fits {out['spread_deg']:.4f} °")
        for k, h in enumerate(out["hypotheses"][1:], start=2):
            typer.echo(f"hypothesis {k}: camera θ φ ψ ° {fmt(h['rotation_angles_deg'])}  score {h['score']:.3f}")
    raise typer.Exit(0 if out["status"] == 0 else 1)


@app.command()
def version():
    """Print the installed version."""
    from importlib.metadata import version as v

    typer.echo(v("jaxpose"))


if __name__ == "__main__":  # pragma: no cover
    app()
