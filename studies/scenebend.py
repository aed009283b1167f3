"""The real-sets study with each scene edge's own bend integrated out in the solve (SolveParams.scene_sag, px), and
optionally the third-order field lookup of studies.lookup (docs/studies/real-sets.md, "A scene edge's own bend in
the solve"): tried, not landed.

    python -m studies.scenebend 0.1 old runs/rs-s0.1-old        # then the real-sets study's own arguments
    python -m studies.scenebend 0.1 cr runs/rs-s0.1-cr
"""
from __future__ import annotations

import contextlib
import functools
import sys

import appdgen.detect.detector as detector_module
from appdgen.detect.solve import SolveParams
from studies import realsets
from studies.lookup import swapped


def main(argv: list[str]) -> None:
    """SAG LOOKUP(old|cr) OUT [realsets arguments]."""
    sag, lookup, out = float(argv[0]), argv[1], argv[2]
    detector_module.SolveParams = functools.partial(SolveParams, scene_sag=sag)
    with swapped() if lookup == "cr" else contextlib.nullcontext():
        realsets.main(["--out", out, *argv[3:]])


if __name__ == "__main__":
    main(sys.argv[1:])
