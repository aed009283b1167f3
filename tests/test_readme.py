"""The README's and docs/'s marked blocks, run exactly as written in a fresh folder; their tables against the code
that owns the names; every relative link of the pages."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from appdgen import lens
from appdgen.dataset.layout import INDEX_ONLY, label_schema

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: The pages: the README and the manual under docs/.
PAGES = (ROOT / "README.md", *sorted(DOCS.rglob("*.md")))
#: Every marked block (<!-- name --> … <!-- /name -->) and the page that holds it; a test below reads each.
BLOCKS = {"quickstart": "README.md", "pandas": "README.md", "python": "README.md",
          "reading-a-build": "docs/output-format.md", "label-columns": "docs/output-format.md",
          "build-json": "docs/output-format.md"}
#: pyarrow's type names as the pages write them.
TYPE_NAMES = {"double": "float64"}


def page_text(page: Path) -> str:
    """A page's Markdown."""
    return page.read_text(encoding="utf-8")


def marked(name: str) -> str:
    """The text between <!-- name --> and <!-- /name --> on the page BLOCKS names for it."""
    text = page_text(ROOT / BLOCKS[name])
    block = re.search(rf"<!-- {name} -->\n(.*?)<!-- /{name} -->", text, re.S)
    assert block, f"{BLOCKS[name]} lost its {name} block"
    return block.group(1)


def code_block(name: str, language: str) -> str:
    """The code of the first ```language block inside the marked block `name`."""
    block = re.match(rf"\s*```{language}\n(.*?)```", marked(name), re.S)
    assert block, f"{BLOCKS[name]}: the {name} block lost its {language} code"
    return block.group(1)


def shown_after(name: str) -> str:
    """The plain ``` block right after the marked block `name`: the output the page says it prints."""
    shown = re.search(rf"<!-- /{name} -->\s*```\n(.*?)```", page_text(ROOT / BLOCKS[name]), re.S)
    assert shown, f"{BLOCKS[name]} lost the output of its {name} block"
    return shown.group(1)


def table_rows(name: str) -> list[list[str]]:
    """The cells of each body row of the Markdown table inside the marked block `name`."""
    lines = [line for line in marked(name).splitlines() if line.startswith("|")]
    return [[cell.strip() for cell in line.strip("|").split(" | ")] for line in lines[2:]]


def ticked(text: str) -> list[str]:
    """The `backticked` names in a table cell, in order."""
    return re.findall(r"`([^`]+)`", text)


def this_checkout() -> dict[str, str]:
    """The environment with this checkout first on PYTHONPATH, so that a subprocess imports this appdgen."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}


def run_python(code: str, folder: Path) -> str:
    """Run `code` with this checkout's appdgen in `folder`, check it succeeds, and return its stdout."""
    result = subprocess.run([sys.executable, "-c", code], cwd=folder, env=this_checkout(), capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return result.stdout


def quickstart_commands() -> list[str]:
    """The shell lines of the README's quick start."""
    return [line for line in code_block("quickstart", "bash").splitlines()
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


def test_every_marked_block_is_one_that_a_test_reads() -> None:
    found = {name: page.relative_to(ROOT).as_posix() for page in PAGES
             for name in re.findall(r"<!-- ([\w-]+) -->", page_text(page))}
    assert found == BLOCKS


def test_readme_quickstart_runs_as_written(quickstart: Path) -> None:
    assert len(list((quickstart / "shards").glob("shard-*.tar"))) == 2
    assert (quickstart / "shards" / "labels.parquet").is_file()


def test_readme_pandas_block_prints_what_it_says(quickstart: Path) -> None:
    pytest.importorskip("pandas")
    assert run_python(code_block("pandas", "python"), quickstart) == shown_after("pandas")


def test_reading_a_build_prints_what_it_says(quickstart: Path) -> None:
    assert run_python(code_block("reading-a-build", "python"), quickstart) == shown_after("reading-a-build")


def test_readme_python_example_prints_what_it_shows(tmp_path: Path) -> None:
    block = re.fullmatch(r"\s*```python\n(.*?)```\s*```\n(.*?)```\s*", marked("python"), re.S)
    assert block, "README.md: the python block is no longer code then its output"
    code, shown = block.groups()
    for name in ("load", "rectify", "appd", "Sampler", "BuildConfig", "build", "open_build", "AppdgenError"):
        assert f"appdgen.{name}" in code, name  # every public name of the section is exercised
    assert run_python(code, tmp_path) == shown
    assert len(list((tmp_path / "shards").glob("shard-*.tar"))) == 2


# --- the output format's tables against their owners ------------------------------------------------------------


def documented_columns(coefficients: tuple[str, ...]) -> list[tuple[str, str]]:
    """(name, type) per labels.parquet column as docs/output-format.md lists them, for a model's coefficients."""
    columns = []
    for names, types, _ in table_rows("label-columns"):
        names = list(coefficients) if names == "the model's coefficients" else ticked(names)
        kinds = types.split(", ")
        assert len(kinds) in (1, len(names)), (names, types)
        columns += zip(names, kinds * len(names) if len(kinds) == 1 else kinds, strict=False)
    return columns


@pytest.mark.parametrize("model", sorted(lens.MODELS))
def test_the_label_columns_page_is_label_schema(model: str) -> None:
    schema = label_schema(("fx", "fy", "cx", "cy", *lens.get(model).PARAMS), sources=True)
    expected = [(field.name, TYPE_NAMES.get(str(field.type), str(field.type))) for field in schema]
    assert documented_columns(lens.get(model).PARAMS) == expected


def test_the_json_member_row_names_the_index_only_columns() -> None:
    text = page_text(DOCS / "output-format.md")
    row = re.search(r"^\| `<key>\.json` \|(.*)$", text, re.M)
    assert row, "docs/output-format.md lost the json member's row"
    assert all(f"`{c}`" in row.group(1) or (c.startswith("crop_") and "`crop_*`" in row.group(1)) for c in INDEX_ONLY)


def test_the_build_json_page_is_a_real_build_json(quickstart: Path) -> None:
    info = json.loads((quickstart / "shards" / "build.json").read_text())
    rows = {key: content for keys, content in table_rows("build-json") for key in ticked(keys)}
    recordings_only = {key for key, content in rows.items() if content.startswith("builds from recordings only")}
    assert set(rows) - recordings_only == set(info)
    params = set(info["calibration"]) - {"path", "camera", "sha256", "width", "height", "model"}
    assert params == {"fx", "fy", "cx", "cy", *lens.get(info["calibration"]["model"]).PARAMS}
    nested = {**{k: v for k, v in info.items() if isinstance(v, dict) and k != "ranges"}, "shards": info["shards"][0]}
    for key, value in nested.items():
        named = set(ticked(rows[key]))
        assert set(value) - (params if key == "calibration" else set()) <= named, (key, set(value) - named)


# --- links -------------------------------------------------------------------------------------------------------


def anchors(page: Path) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces as hyphens."""
    headings = re.findall(r"^#+ (.+)$", re.sub(r"```.*?```", "", page_text(page), flags=re.S), re.M)
    return {re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-") for heading in headings}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_points_to_a_file_and_heading_that_exist(page: Path) -> None:
    text = re.sub(r"```.*?```", "", page_text(page), flags=re.S)
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    for link in links:
        if re.match(r"[a-z]+:", link):
            continue
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        assert target.exists(), f"{page.name}: {link} points to no file"
        if anchor:
            assert target.suffix == ".md" and anchor in anchors(target), f"{page.name}: {link} names no heading"


def test_both_maps_list_every_docs_page() -> None:
    pages = {p.name for p in DOCS.glob("*.md")} - {"README.md"}
    readme_map = page_text(ROOT / "README.md").split("## Documentation", 1)[1]
    assert set(re.findall(r"\]\(docs/([\w-]+\.md)\)", readme_map)) == pages
    assert set(re.findall(r"\]\(([\w-]+\.md)\)", page_text(DOCS / "README.md"))) == pages


# --- the package's entry points ----------------------------------------------------------------------------------


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


def test_every_make_target_is_in_the_cli_pages_table() -> None:
    targets: set[str] = set()
    for makefile in ("Makefile", "studies.mk"):
        text = (ROOT / makefile).read_text(encoding="utf-8").replace("\\\n", " ")
        targets |= {name for line in re.findall(r"^\.PHONY:(.*)$", text, re.M) for name in line.split()}
    assert {"demo", "test", "train", "real-sets", "detect-study"} <= targets
    table = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"`make ([a-z-]+)`", table))
    assert targets - listed == set(), targets - listed
    rules = {m for makefile in ("Makefile", "studies.mk")
             for m in re.findall(r"^([a-z][a-z-]*):", (ROOT / makefile).read_text(encoding="utf-8"), re.M)}
    assert rules - targets == set(), rules - targets  # every target is declared phony, so none is left out above
