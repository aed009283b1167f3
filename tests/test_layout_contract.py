"""The build folder has one owner of its names: rename them in layout.py alone and build, open_build, inspect,
verify, the trainer's loader and its synthetic shards still work end to end, under the new names."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from helpers import Setup

ROOT = Path(__file__).resolve().parents[1]

#: Edits to layout.py's text, as a maintainer renaming the outputs would make them.
RENAMES = {"labels.parquet": "index2.parquet", "build.json": "summary2.json", "plan.json": "plan2.json",
           '".parts"': '".work"', "shard-": "part-"}

# Run in a fresh interpreter: layout.py's renamed text is loaded as appdgen.dataset.layout before anything imports
# it, exactly as if the file had been edited; every other module takes the names from there.
SCRIPT = textwrap.dedent("""
    import json, sys, types
    from pathlib import Path

    root, renames, calib, images, out, synthetic, run = sys.argv[1:]
    renames = json.loads(renames)
    path = Path(root) / "appdgen" / "dataset" / "layout.py"
    source = path.read_text()
    for old, new in renames.items():
        source = source.replace(old, new)
    layout = types.ModuleType("appdgen.dataset.layout")
    layout.__file__ = str(path)
    sys.modules[layout.__name__] = layout
    exec(compile(source, str(path), "exec"), layout.__dict__)

    from click.testing import CliRunner
    from appdgen.cli import main
    from appdgen.dataset.reader import open_build

    def cli(*args):
        result = CliRunner().invoke(main, [str(a) for a in args])
        assert result.exit_code == 0, result.output
        return result.output

    cli("build", "--calib", calib, "--images", images, "--out", out, "--samples", 24, "--shard-size", 8,
        "--size", "87x32", "--seed", 7, "--jobs", 1, "--quiet")
    build = open_build(out)
    report = {"files": sorted(p.name for p in Path(out).iterdir()), "count": build.count,
              "shards": [p.name for p in build.shards], "splits": build.splits,
              "samples": [(key, image.shape, row["appd_pct"]) for key, image, row in build.samples()],
              "inspect": cli("inspect", out), "verify": cli("verify", out)}

    from train.cli import main as train
    from appdgen.dataset.shardset import open_shards
    from train.data import Selection, ShardStream, StreamSpec
    sys.path.insert(0, str(Path(root) / "tests"))
    from synthetic_shards import write_shards

    shards = open_shards(out)
    report["read_by_trainer"] = [list(shards.size), shards.split_count("all"), len(shards.shards)]
    report["loaded"] = sorted(s["key"] for s in ShardStream(StreamSpec(shards.for_split("all"), Selection("all"))))
    write_shards(synthetic, n=16, per_shard=8)
    report["synthetic"] = sorted(p.name for p in Path(synthetic).iterdir())
    report["verify_synthetic"] = cli("verify", synthetic)
    train(["fit", "--shards", synthetic, "--run", run, "--steps", "2", "--batch", "4", "--workers", "0",
           "--stats-samples", "4", "--quiet"])
    print(json.dumps(report))
""")


@pytest.mark.slow
def test_renaming_the_outputs_in_layout_alone_keeps_everything_working(setup: Setup, tmp_path: Path) -> None:
    pytest.importorskip("torch")
    out, synthetic, run = tmp_path / "out", tmp_path / "synthetic", tmp_path / "run"
    done = subprocess.run([sys.executable, "-c", SCRIPT, str(ROOT), json.dumps(RENAMES), str(setup.calib),
                           str(setup.images), str(out), str(synthetic), str(run)], capture_output=True, text=True,
                          timeout=600, cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.splitlines()[-1])
    assert report["files"] == ["index2.parquet", "part-000000.tar", "part-000001.tar", "part-000002.tar",
                               "summary2.json"]
    assert report["synthetic"] == ["index2.parquet", "part-000000.tar", "part-000001.tar", "summary2.json"]
    assert report["count"] == 24 and report["splits"] == {"all": 24}
    assert report["shards"] == ["part-000000.tar", "part-000001.tar", "part-000002.tar"]
    assert [key for key, _, _ in report["samples"]] == [f"{i:09d}" for i in range(24)]
    assert all(shape == [32, 87, 3] for _, shape, _ in report["samples"])
    assert "24 samples in 3 shards" in report["inspect"] and "index2.parquet" in report["inspect"]
    assert report["verify"].strip() == "verified 24 samples in 3 shards: OK"
    assert report["verify_synthetic"].strip() == "verified 16 samples in 2 shards: OK"
    assert report["read_by_trainer"] == [[87, 32], 24, 3]  # the summary found, not just the shards by name
    assert report["loaded"] == [f"{i:09d}" for i in range(24)]
    assert (run / "last.pt").is_file()
