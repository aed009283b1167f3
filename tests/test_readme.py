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
                            env=this_checkout(), capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout == shown.group(1)


def this_checkout() -> dict[str, str]:
    """The environment with this checkout first on PYTHONPATH, so that a subprocess imports this appdgen."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


def python_section() -> tuple[str, str]:
    """The README's Python example between <!-- python --> and <!-- /python -->: (its code, the output it shows)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- python -->\s*```python\n(.*?)```\s*```\n(.*?)```\s*<!-- /python -->", text, re.S)
    assert block, "README.md lost its Python example"
    return block.group(1), block.group(2)


def test_readme_python_example_prints_what_it_shows(tmp_path):
    code, shown = python_section()
    for name in ("load", "rectify", "appd", "Sampler", "BuildConfig", "build", "open_build", "AppdgenError"):
        assert f"appdgen.{name}" in code, name  # every public name of the section is exercised
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=this_checkout(),
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout == shown
    assert len(list((tmp_path / "shards").glob("shard-*.tar"))) == 2


def test_the_public_names_load_lazily_from_their_owners():
    code = ("import sys, appdgen; heavy = [m for m in ('yaml', 'pyarrow') if m in sys.modules]; "
            "from appdgen.dataset.build import build; from appdgen.calib.formats import load; "
            "print(heavy, appdgen.build is build, appdgen.load is load, "
            "sorted(set(appdgen.__all__) - set(dir(appdgen))))")
    result = subprocess.run([sys.executable, "-c", code], env=this_checkout(), capture_output=True, text=True,
                            timeout=60)
    assert result.stdout.strip() == "[] True True []", result.stderr


def test_python_m_appdgen_runs_the_command_line():
    result = subprocess.run([sys.executable, "-m", "appdgen", "build", "--help"], env=this_checkout(),
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and "--calib" in result.stdout, result.stderr
