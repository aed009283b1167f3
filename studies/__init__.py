"""Research on top of the product: studies that import the trainer (train/) and appdgen, which import nothing of
them. Run from the repository's root, e.g. `python -m studies.detector --tiny`, `python -m studies.experiment --tiny`.

Modules: detector (the detector comparison: networks, targets and the plumb-line floor side by side on the same
fresh pairs, scored on the axes of novelty), experiment (the paper-scale experiment in one call: synth, build, fit,
evaluate).
"""
