"""The generator: sample → rectify → label → shard, in parallel, deterministic and resumable.

Shard k holds samples [k·S, (k+1)·S). A worker (worker.py) builds a whole shard's tar (written atomically); the
parent then writes its label rows and stats as a Parquet fragment under `.parts/` (the fragment marks the shard
done). Resume skips done shards (folder.py); the index and build.json (summary.py) are written once every shard is
done. Bytes depend on the inputs, options and seed only (plan.py), never on --jobs or on scheduling. File names come
from appdgen.dataset.layout.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

from appdgen.dataset.folder import add_bend_columns, pending_shards, prepare_out
from appdgen.dataset.plan import BuildConfig
from appdgen.dataset.summary import summary
from appdgen.dataset.worker import build_shard
from appdgen.errors import AppdgenError
from appdgen.sampling.reach import UnreachableError
from appdgen.sources.raw import RawImageError
from appdgen.util.distribute import check_parallel, run_unordered
from appdgen.util.progress import Progress

if TYPE_CHECKING:  # workers never import pyarrow (~80 ms of each one's start): the parent writes the fragments
    import pyarrow as pa


def build(config: BuildConfig, out: Path, jobs: int = 1, backend: str = "loky", scheduler: str | None = None,
          resume: bool = False, overwrite: bool = False, progress: bool = True, command: list[str] | None = None,
          skipped: list[dict] | None = None) -> dict:
    """Run a build into `out` and return build.json's content (skipped: images left out, {"path", "problem"})."""
    start = time.perf_counter()
    check_parallel(jobs, backend)
    # Refuses bad --appd-max, --zero-fraction and --ranges, and an --appd-max the ranges cannot reach, here where
    # the build starts (a few dozen coarse APPD evaluations), before --out is touched, not in a worker; the sampler
    # is the one an in-process build (--jobs 1) goes on to use.
    config.sampler().check_reachable()
    config = prepare_out(out, config, resume, overwrite)
    writer = config.writer(out)
    todo = pending_shards(out, config)
    if resume:
        add_bend_columns(config, writer, [k for k in range(config.shard_count) if k not in todo])
    bar = Progress(config.samples, enabled=progress,
                   done=config.samples - sum(len(config.shard_samples(k)) for k in todo))
    bar.advance(0, "resumed" if resume else "")
    made: dict[int, pa.Table] = {}  # this run's fragments, kept for the index (re-reading them cost ~3 ms each)
    try:
        for stats, rows in run_unordered(build_shard, [(config, str(out), k) for k in todo], jobs, backend, scheduler):
            made[stats.shard] = writer.shard_done(stats, rows)  # after the shard's tar: marks the shard done
            bar.advance(stats.samples, stats.file)
        return writer.finish(config.shard_count, made, lambda stats: summary(
            config, stats, list(made), time.perf_counter() - start, command, skipped or []))
    except OSError as exc:
        reason = exc.strerror or exc
        raise AppdgenError(f"--out {out}: write failed ({reason}); fix it and rerun with --resume") from None
    except UnreachableError as exc:
        raise AppdgenError(f"{exc}, then rebuild with --overwrite (--resume refuses other options)") from None
    except RawImageError as exc:
        raise AppdgenError(f"{exc} (finished shards are kept: replace the file and rerun with --resume, or leave it "
                           f"out and rebuild with --overwrite)") from None
    except AppdgenError as exc:
        raise AppdgenError(f"{exc} (finished shards are kept: fix this and rerun with --resume)") from None

