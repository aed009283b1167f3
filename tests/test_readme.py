"""The README's quick start, run exactly as written, in a fresh folder."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_block(name: str, language: str) -> str:
    """The code block of the README between <!-- name --> and <!-- /name -->."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(rf"<!-- {name} -->\s*```{language}\n(.*?)```\s*<!-- /{name} -->", text, re.S)
    assert block, f"README.md lost its {name} block"
    return block.group(1)


def quickstart_commands() -> list[str]:
    """The shell lines of the README's quick start."""
    return [line for line in readme_block("quickstart", "bash").splitlines()
            if line.strip() and not line.startswith("#")]


@pytest.fixture(scope="module")
def quickstart(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder after the quick start's commands, each run as written and checked to succeed."""
    folder = tmp_path_factory.mktemp("quickstart")
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    commands = quickstart_commands()
    assert any(c.startswith("appdgen build") for c in commands)
    for command in commands:
        result = subprocess.run(command, shell=True, cwd=folder, env=env, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, f"{command}\n{result.stderr}"
    return folder


def test_readme_quickstart_runs_as_written(quickstart: Path) -> None:
    assert len(list((quickstart / "shards").glob("shard-*.tar"))) == 2
    assert (quickstart / "shards" / "labels.parquet").is_file()


def test_readme_reading_a_build_prints_what_it_says(quickstart: Path) -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    shown = re.search(r"<!-- /reading-a-build -->\s*```\n(.*?)```", text, re.S)
    assert shown, "README.md lost the output of its reading-a-build block"
    result = subprocess.run([sys.executable, "-c", readme_block("reading-a-build", "python")], cwd=quickstart,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout == shown.group(1)
