"""The package's layout (issues 19 and 24, docs/architecture.md): folders by pipeline stage, no import running back up
the flow (the trainer, train/, included), no import circle even inside a folder, few loose modules, no class over 200
lines outside synth/.

Imports are read from the source (ast), lazy ones inside functions and TYPE_CHECKING blocks included: a lazy import
that closes a circle couples the two modules as much as a top-level one (lazy imports stay for what is costly or
optional to load, which never needs a circle). A parent package's __init__, which Python runs first, is not counted
as imported unless it is named."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "appdgen"
TRAINER = ROOT / "train"
STUDIES = ROOT / "studies"
PACKAGES = ("appdgen", "train", "studies")
#: The flow, ground first: a module may import its own stage and earlier ones only; synth and analysis sit side by
#: side (neither imports the other); the package's own __init__/__main__ (the public names, python -m) are the top.
#: sources (what turns --images into frames) sits below dataset: the build imports the frames, sources import
#: nothing of the build folder. The trainer (train/) sits over the library and below appdgen's CLI, which it may
#: not import; its own CLI (train.cli, train.__main__) sits over appdgen.cli, whose shared click options it reuses.
#: appdgen imports nothing of train. The studies (studies/: research over the trainer and appdgen) are the top:
#: nothing imports them.
STAGES: dict[str, int] = {"errors": 0, "version": 0, "util": 1, "lens": 2, "calib": 3, "geometry": 4, "sampling": 5,
                          "sources": 6, "dataset": 7, "detect": 7, "synth": 8, "analysis": 8, "train": 9, "cli": 10,
                          "train.cli": 11, "__init__": 12, "__main__": 12, "studies": 13}
#: What the ground may import of appdgen.
GROUND: dict[str, set[str]] = {"errors": set(), "version": set(), "util": {"errors"}}
LOOSE_ALLOWED = {"__init__", "__main__", "errors"}


def stage(module: str) -> str:
    """The stage of a dotted module ('appdgen.calib.formats' → 'calib'; 'appdgen' → '__init__'; 'train.fit' →
    'train'; 'train.cli', 'train.__main__' → 'train.cli')."""
    parts = module.split(".")
    if parts[0] == "studies":
        return "studies"
    if parts[0] == "train":
        return "train.cli" if parts[1:2] in (["cli"], ["__main__"]) else "train"
    return parts[1] if len(parts) > 1 else "__init__"


def modules(roots: tuple[Path, ...] = (PACKAGE,)) -> dict[str, Path]:
    """Every module of the packages by dotted name (appdgen's alone by default)."""
    found = {}
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            parts = path.relative_to(root.parent).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" and len(parts) > 1 else parts)] = path
    return found


def imported(path: Path) -> set[str]:
    """The appdgen and train modules a file imports anywhere in it (lazy imports inside functions included);
    `from appdgen import x` counts as appdgen.x when x is a subpackage or module, else as the package's own
    __init__ (and so for train)."""
    names: set[str] = set()
    known = modules((PACKAGE, TRAINER, STUDIES))
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.split(".")[0] in PACKAGES}
        elif isinstance(node, ast.ImportFrom) and node.level:
            raise AssertionError(f"{path}: relative import")
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES:
            for alias in node.names:
                names.add(f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in known else node.module)
    return names


def import_graph() -> dict[str, set[str]]:
    """Module → the modules it imports, over appdgen, train and studies."""
    return {name: imported(path) for name, path in modules((PACKAGE, TRAINER, STUDIES)).items()}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of a graph: its strongly connected components of more than one module, or of one
    module importing itself (Tarjan's algorithm, iterative), each sorted."""
    order: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []
    for start in sorted(graph):
        if start in order:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        order[start] = low[start] = len(order)
        stack.append(start)
        while work:
            node, targets = work[-1]
            for target in targets:
                if target not in order:
                    order[target] = low[target] = len(order)
                    stack.append(target)
                    work.append((target, iter(sorted(graph.get(target, ())))))
                    break
                if target in stack:
                    low[node] = min(low[node], order[target])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == order[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1 or node in graph.get(node, ()):
                        found.append(sorted(component))
    return found


def test_the_stage_table_names_every_folder_and_loose_module() -> None:
    present = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
               if (p.is_file() and p.suffix == ".py") or (p / "__init__.py").is_file()}
    assert present <= set(STAGES), sorted(present - set(STAGES))


def test_no_module_imports_from_a_later_stage() -> None:
    upward = []
    for name, path in modules((PACKAGE, TRAINER, STUDIES)).items():
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


def test_the_trainer_is_under_the_stage_order() -> None:
    # train/ is read by the test above: no train module but its CLI imports appdgen.cli, appdgen imports no train.
    graph = import_graph()
    assert any(stage(name) == "train" for name in graph)
    assert not [(n, t) for n, ts in graph.items() for t in ts if stage(n) == "train" and stage(t) == "cli"]
    assert not [(n, t) for n, ts in graph.items() for t in ts if n.startswith("appdgen") and t.startswith("train")]


def test_the_studies_sit_on_top_and_nothing_imports_them() -> None:
    # Research imports the product, never the reverse: no appdgen or train module imports studies/, and what
    # evaluate reports (train.scoring) is the trainer's, so editing a study cannot change `evaluate`.
    graph = import_graph()
    assert {"studies.detector", "studies.experiment"} <= set(graph)
    assert any(t.startswith("train") for t in graph["studies.detector"])
    research = [(n, t) for n, ts in graph.items() for t in ts if t.startswith("studies")]
    assert not [(n, t) for n, t in research if not n.startswith("studies")]
    assert not [t for t in graph["train.evaluate"] if t.startswith("studies")]
    assert "train.scoring" in graph["train.evaluate"]


def test_the_package_list_installs_appdgen_alone() -> None:
    # train/ and studies/ are folders of the repository, run from its root (python -m train): nothing installs a
    # generic top-level `train` into site-packages (issue 31).
    import tomllib
    from setuptools import find_packages

    find = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    installed = find_packages(str(ROOT), include=find["include"], exclude=find.get("exclude", ()))
    assert "appdgen" in installed and "appdgen.cli" in installed
    assert not [p for p in installed if p.split(".")[0] != "appdgen"], installed
    assert "train" in find_packages(str(ROOT), include=["appdgen*", "train*"])  # the check can fail: the old list


def test_no_import_circle_not_even_inside_a_folder() -> None:
    assert not circles(import_graph())


def test_a_circle_is_caught() -> None:
    # The circle check must be able to fail: a two-module circle inside one folder, a self-import, a long loop.
    graph = {"a.x": {"a.y"}, "a.y": {"a.x", "b"}, "b": set(), "c": {"c"}, "d": {"e"}, "e": {"f"}, "f": {"d"}}
    assert sorted(circles(graph)) == [["a.x", "a.y"], ["c"], ["d", "e", "f"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_the_online_fit_takes_its_inputs_from_sources_not_the_build_folder() -> None:
    # fit --online reads --images through appdgen.sources; appdgen.dataset is the build folder, which only the
    # offline fit, evaluate and predict read (through dataset.reader / dataset.layout).
    graph = import_graph()
    online = {n: ts for n, ts in graph.items() if n.startswith("train.online") or n == "train.holdout"}
    assert "train.online.recipe" in online
    assert any(t.startswith("appdgen.sources") for t in online["train.online.recipe"])
    assert not [(n, t) for n, ts in online.items() for t in ts if t.startswith("appdgen.dataset")]
