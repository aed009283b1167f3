"""`fit --online`: every training image a fresh pair (training frame, calibration) drawn as training goes.

Image i of a run is the pair that numpy's SeedSequence([seed, i]) chooses: its calibration is the build sampler's
draw(seed, i) (the same Θm, crop and label `appdgen build --seed SEED` gives sample i), its frame comes from
SeedSequence([seed, i, FRAME_STREAM]). Batch j holds images j·B … (j+1)·B − 1 (times the ranks), whichever
loader worker makes it, so a run is reproducible for any --workers and --resume continues exactly. Raw frames are
decoded once and kept in memory (on the training device for --render device). Renderers: `cpu` remaps in the
loader workers with OpenCV exactly as build does (geometry.remap.remap_image of the draw's rectification);
`device` draws in the workers and rectifies on the training device (train.warp.rectify_batch, grid_sample).
Validation uses fixed-seed pairs (VAL_SEED) of held-out frames, rendered once, so numbers compare between runs.

Modules: options (OnlineOptions, --render), recipe (the camera, size and sampling options every pair is drawn with;
the raw frames decoded), pairs (which frame and draw image i is; the loader of pair batches), render (pairs rendered
on the training device; the feed that times the data), trainer (a run's data and the train.loop.Trainer it feeds).
Which frames validate is train.holdout's rule, shared with the offline fit.
"""
