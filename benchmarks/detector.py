"""Detectors side by side (issue 23): the paper's CNN at low resolution, the stride-4 patch network at full
resolution on a scalar and on a dense target, the plumb-line floor; each on APPD and bend; per image and per
sequence, on the training views, a new viewpoint of the training streets, unseen streets and (given) real frames.

    python benchmarks/detector.py [--tiny] [--images 4000] [--frames 300] [--sequences 16] [--out runs/detector]
    python benchmarks/detector.py --calib ../shared/data/real/euroc_micro_cam1/sensor.yaml \\
        --real ../shared/data/real/euroc_micro_cam1/data --low-scale 0.5 --grey   # sim-to-real

Every network arm trains on the same --images fresh pairs (fit --online's source), so machine load changes the
minutes, not the comparison; the two streams run at once, one core each. Prints one markdown table (train.detector's
columns) and a JSON line with the command, the CPU seconds and the load average.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import fields, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from train.detector import TINY, DetectorOptions, run, table  # noqa: E402


def options(argv: list[str] | None = None) -> DetectorOptions:
    """DetectorOptions from the command line (--tiny: TINY's sizes where not given)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tiny", action="store_true", help="All arms in a few minutes on 2 cores: the chain only.")
    parser.add_argument("--arms", help="Comma-separated arm names (default: all), e.g. paper/appd,patch/field.")
    for f in fields(DetectorOptions):
        if f.name == "arms":
            continue
        flag = "--" + f.name.replace("_", "-")
        if f.type == "bool":
            parser.add_argument(flag, action="store_true")
        else:
            kind = {"int": int, "float": float}.get(f.type, str)
            parser.add_argument(flag, type=kind, default=None)
    args = parser.parse_args(argv)
    given = {f.name: getattr(args, f.name) for f in fields(DetectorOptions)
             if f.name != "arms" and getattr(args, f.name) not in (None, False)}
    o = DetectorOptions(**given)
    if args.tiny:
        o = replace(o, **{k: v for k, v in TINY.items() if k not in given})
    if args.arms:
        o = replace(o, arms=tuple(args.arms.split(",")))
    return o


def main(argv: list[str] | None = None) -> dict:
    """Run the comparison and print its table and a JSON line."""
    o = options(argv)
    load_before = os.getloadavg()
    summary = run(o)
    print(table(summary["rows"]))
    print(json.dumps({"command": " ".join(["python", "benchmarks/detector.py", *(argv or sys.argv[1:])]),
                      "wall_s": round(summary["wall_s"]), "synth_s": round(summary["synth_s"]),
                      "load_before": load_before, "load_after": os.getloadavg(),
                      "streams": summary["streams"]}))
    return summary


if __name__ == "__main__":
    main()
