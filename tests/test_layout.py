"""The package's layout (issue 19, docs/architecture.md): folders by pipeline stage, no import running back up the
flow, few loose modules, no class over 200 lines outside synth/."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "appdgen"
#: The flow, ground first: a module may import its own stage and earlier ones only; synth and analysis sit side by
#: side (neither imports the other); the package's own __init__/__main__ (the public names, python -m) are the top.
STAGES: dict[str, int] = {"errors": 0, "version": 0, "util": 1, "lens": 2, "calib": 3, "geometry": 4, "sampling": 5,
                          "sources": 6, "dataset": 7, "synth": 8, "analysis": 8, "cli": 9, "__init__": 10,
                          "__main__": 10}
#: What the ground may import of appdgen.
GROUND: dict[str, set[str]] = {"errors": set(), "version": set(), "util": {"errors"}}
LOOSE_ALLOWED = {"__init__", "__main__", "errors"}


def stage(module: str) -> str:
    """The stage of a dotted module under appdgen ('appdgen.calib.formats' → 'calib'; 'appdgen' → '__init__')."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def modules() -> dict[str, Path]:
    """Every module of the package by dotted name."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" and len(parts) > 1 else parts)] = path
    return found


def imported(path: Path) -> set[str]:
    """The appdgen modules a file imports anywhere in it (lazy imports inside functions included); `from appdgen
    import x` counts as appdgen.x when x is a subpackage or module, else as the package's own __init__."""
    names: set[str] = set()
    known = modules()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.split(".")[0] == "appdgen"}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "appdgen":
            assert node.level == 0, f"{path}: relative import"
            for alias in node.names:
                names.add(f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in known else node.module)
    return names


def test_the_stage_table_names_every_folder_and_loose_module() -> None:
    present = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
               if (p.is_file() and p.suffix == ".py") or (p / "__init__.py").is_file()}
    assert present <= set(STAGES), sorted(present - set(STAGES))


def test_no_module_imports_from_a_later_stage() -> None:
    upward = []
    for name, path in modules().items():
        mine = stage(name)
        for target in imported(path):
            theirs = stage(target)
            if theirs == mine:
                continue
            if STAGES[theirs] >= STAGES[mine]:
                upward.append(f"{name} imports {target}")
    assert not upward, upward


@pytest.mark.parametrize("ground", sorted(GROUND))
def test_the_ground_imports_nothing_of_appdgen_but_errors(ground: str) -> None:
    for name, path in modules().items():
        if stage(name) == ground:
            others = {t for t in imported(path) if stage(t) not in GROUND[ground] | {ground}}
            assert not others, (name, others)


def test_at_most_three_loose_modules() -> None:
    loose = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem not in LOOSE_ALLOWED)
    assert len(loose) <= 3, loose


def test_no_class_over_200_lines_outside_synth() -> None:
    long = []
    for name, path in modules().items():
        if stage(name) == "synth":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > 200:
                long.append(f"{name}.{node.name}: {node.end_lineno - node.lineno + 1} lines")
    assert not long, long


def test_a_module_importing_upwards_is_caught(tmp_path: Path) -> None:
    # The checks above must be able to fail: an import of the sampler from the calibration stage is upward.
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from appdgen.sampling.sampler import Sampler\n\nfrom appdgen import lens\n")
    assert imported(probe) == {"appdgen.sampling.sampler", "appdgen.lens"}
    assert STAGES[stage("appdgen.sampling.sampler")] > STAGES["calib"]
