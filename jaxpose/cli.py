"""The `jaxpose` command line (typer). Degrees and centimetres at this boundary only."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(help="jaxpose: pose change of an unknown-shape target from two lidar clouds.", no_args_is_help=True)


@app.command()
def paper(out: Annotated[Path, typer.Option(help="Folder for the Markdown table.")] = Path("results")):
    """The paper's test example: simulated cloud statistics and N5 intersection patterns."""
    from rich.console import Console
    from rich.markdown import Markdown

    from .report import cloud_statistics, markdown_tables, n5_patterns

    text = markdown_tables(cloud_statistics(), n5_patterns())
    Console().print(Markdown(text))
    out.mkdir(parents=True, exist_ok=True)
    (out / "paper_patterns.md").write_text(text + "\n")
    typer.echo(f"wrote {out / 'paper_patterns.md'}")


@app.command()
def version():
    """Print the installed version."""
    from importlib.metadata import version as v

    typer.echo(v("jaxpose"))


if __name__ == "__main__":  # pragma: no cover
    app()
