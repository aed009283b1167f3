# Research targets (included by the Makefile): the studies on top of the product, each with its page in
# docs/studies/. They use the Makefile's PY, APPDGEN, STAMP, TRAIN_STAMP and DEMO; sizes go in ARGS.
.PHONY: train-one-scene paper-scale paper-scale-tiny paper-scale-detector detector detector-tiny detect-study \
	detect-study-tiny real-sets device-wheels

# The whole chain (build, shards, fit, evaluate) with scene variety removed: one synthetic frame, its samples split
# 50/50 into train and test; the CNN only has to read how the frame is warped (docs/studies/learnability.md).
ONE := $(DEMO)/one-scene
train-one-scene: $(TRAIN_STAMP)
	rm -rf $(ONE)
	$(APPDGEN) synth --frames 1 --scale 0.25 --seed 1 --out $(ONE)/raw/train --quiet
	$(APPDGEN) synth --frames 1 --scale 0.25 --seed 1 --out $(ONE)/raw/test --quiet
	$(APPDGEN) build --calib $(ONE)/raw/train/calibration.yaml --images $(ONE)/raw --split-by parent \
		--samples 3000 --shard-size 500 --out $(ONE)/shards --quiet
	$(PY) -m train fit --shards $(ONE)/shards --split train --val-split none --run $(ONE)/run --epochs 30 \
		--max-minutes 3 --quiet
	$(PY) -m train evaluate --ckpt $(ONE)/run/last.pt --shards $(ONE)/shards --split test --json $(ONE)/eval.json

# The accelerator experiment (docs/studies/accelerator-experiment.md): full-size synthetic KITTI 02 frames, samples,
# a timed fit of the paper's CNN, test MAE against the mean predictor in one line; sized for one H200 with 16 cores
# (ARGS="--minutes 3 --samples 8000" ...).
paper-scale: $(TRAIN_STAMP)
	$(PY) -m studies.experiment --out runs/paper-scale --overwrite $(ARGS)

# The same code at 348x128 with small sizes on 2 CPU cores: proves the chain, not the quality.
paper-scale-tiny: $(TRAIN_STAMP)
	$(PY) -m studies.experiment --tiny --out runs/paper-scale-tiny --overwrite $(ARGS)

# The detector comparison for the accelerator (docs/studies/detector-comparison.md): every arm (the paper's CNN at
# 348x128, the patch network at 1392x512 on appd, bend and the dense field, the plumb-line floor) on --samples fresh
# pairs each.
paper-scale-detector: $(TRAIN_STAMP)
	$(PY) -m studies.experiment --detector --out runs/paper-scale-detector --samples 8000 $(ARGS)

# The same comparison on 2 CPU cores (the table of docs/studies/detector-comparison.md), and its smoke run.
detector: $(TRAIN_STAMP)
	nice -n 10 $(PY) -m studies.detector --images 6000 --frames 300 --sequences 32 --out runs/detector $(ARGS)

detector-tiny: $(TRAIN_STAMP)
	$(PY) -m studies.detector --tiny --out runs/detector-tiny $(ARGS)

# The bend-field estimator (appdgen detect) as an arm of the same comparison: every axis, the sequential test and two
# other lenses (docs/studies/bend-field-detector.md; models cached in runs/bendfield/cache), and its smoke run.
detect-study: $(TRAIN_STAMP)
	nice -n 10 $(PY) -m studies.bendfield --out runs/bendfield $(ARGS)

detect-study-tiny: $(TRAIN_STAMP)
	$(PY) -m studies.bendfield --tiny --out runs/bendfield-tiny $(ARGS)

# appdgen detect on the real frames of ../shared/data/real (the desk, EuRoC cam 1) under their true files and under
# perturbed beliefs, with and without a baseline: error, coverage of its ±, false alarms (docs/detect.md).
real-sets: $(STAMP)
	$(PY) -m studies.realsets --out runs/realsets $(ARGS)

# Wheels the accelerator machine lacks (its python3 has CUDA torch, OpenCV, pyarrow, click, joblib, pyyaml but not
# webdataset): pure-Python, carried in .whl/ (git-ignored); docs/studies/accelerator-experiment.md.
device-wheels: $(STAMP)
	$(PY) -m pip download -q --no-deps --only-binary=:all: -d .whl webdataset==1.0.2 braceexpand==0.1.7
