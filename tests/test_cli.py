from typer.testing import CliRunner

from jaxpose._cli import app


def test_paper_command_prints_and_writes_the_table(tmp_path):
    result = CliRunner().invoke(app, ["paper", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    text = (tmp_path / "paper_patterns.md").read_text()
    assert "| N5 | previous | 4194 | 4219 |" in text
    assert "selected points, paper | 273 | 239 | 85" in text
