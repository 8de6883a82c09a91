"""The documentation site builds without a warning, and the README stays a landing page."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_docs_build_strict(tmp_path):
    """`mkdocs build --strict`: every page in the nav exists, every link and every
    cross-reference of the API reference resolves (the docstrings' `[x][]` included)."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
    )
    assert out.returncode == 0, out.stderr[-4000:]
    assert (tmp_path / "site" / "api" / "index.html").exists()


def test_readme_is_a_landing_page():
    assert len((ROOT / "README.md").read_text()) <= 12_000


def test_the_library_imports_without_the_cli_and_evaluation_dependencies():
    """`import jaxpose` (the library other JAX code imports) loads neither the command line's
    own dependencies (typer, matplotlib: the `cli` extra) nor the evaluation subpackage.
    rich is not checked: evosax's flax imports it."""
    code = (
        "import sys, jaxpose\n"
        "bad = [m for m in ('typer', 'matplotlib', 'jaxpose.evaluation', 'jaxpose._cli') if m in sys.modules]\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
