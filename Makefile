# Two commands do all set-up on a fresh machine: `make demo` (the main job on embedded data) and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
APPDGEN := $(VENV)/bin/appdgen
STAMP := $(VENV)/.installed
TRAIN_STAMP := $(VENV)/.installed-train
DEMO := demo
# The CPU build of torch (an unpinned torch pulls a multi-GB CUDA build).
TORCH := torch==2.13.0

.PHONY: demo test test-core test-slow test-heavy train train-cnn train-one-scene paper-scale paper-scale-tiny paper-scale-detector detector detector-tiny detect-study detect-study-tiny device-wheels bench bench-synth bench-render bench-rss clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

$(TRAIN_STAMP): $(STAMP)
	$(PY) -m pip install -q '$(TORCH)'
	$(PY) -m pip install -q -e '.[test,train,plot,dask,ros,video,fpng]'
	touch $(TRAIN_STAMP)

# Synthetic street frames of a quarter-size KITTI camera 02, split by folder, then ~2,000 labelled samples.
demo: $(STAMP)
	$(APPDGEN) synth --frames 48 --scale 0.25 --seed 1 --out $(DEMO)/raw/train --quiet
	$(APPDGEN) synth --frames 16 --scale 0.25 --seed 2 --out $(DEMO)/raw/test --quiet
	$(APPDGEN) build --calib $(DEMO)/raw/train/calibration.yaml --images $(DEMO)/raw --split-by parent \
		--samples 2000 --shard-size 250 --out $(DEMO)/shards --overwrite
	$(APPDGEN) inspect $(DEMO)/shards --sheet $(DEMO)/sheet.png

# The trainer's tests need torch: the CPU build is installed too (see TORCH); the recordings' tests need the ros and
# video extras (rosbags, PyAV), installed with it. The checks every commit needs: the `slow` ones (make test-slow)
# and the `heavy` ones (make test-heavy) are left out. Measured 2026-12-03 in a fresh clone, set-up excluded, with
# `/usr/bin/time .venv/bin/python -m pytest -q -m "not slow" --durations=30`: 796 tests, 6.7 min of CPU (user+sys),
# 13.1 min wall on 2 cores shared with four other sessions (load average ~7); on idle cores the CPU time bounds the
# wall time (one test at a time). The whole suite before `slow` was left out: 11.5 min of CPU, 20.5 min wall.
# Later the same day, `time CI=true bash .ci/run` in a fresh clone: 858 passed in 4 min 34 s, 6 min 42 s with set-up
# (load ~2; at load ~8: 6 min 53 s and 8 min 53 s; docs/performance.md, "The two commands").
test: $(TRAIN_STAMP)
	$(PY) -m pytest -q -m "not slow"

# The generator alone: make test without torch (the trainer's tests skip). CI keeps `make test`.
test-core: $(STAMP)
	$(PY) -m pytest -q -m "not slow"

# Checks not needed on every commit, left out of make test (`pytest` with no -m runs them too): label flatness of
# the radtan model at 20,000 draws and of the other lens models at 3,000, random kills, the renamed layout, the
# studies' and the plumb-line fit's end-to-end runs, the device renderer on CPU. 13 tests, 9.0 min of CPU (24.8 min
# wall, load ~10; measured as make test's line above, -m slow).
test-slow: $(TRAIN_STAMP)
	$(PY) -m pytest -q -m slow

# Minutes-long checks left out of make test (tests/conftest.py runs `heavy` tests only when asked for): the
# 20,000-draw label uniformity per lens model (~5 min on 2 cores).
test-heavy: $(TRAIN_STAMP)
	$(PY) -m pytest -q -m heavy

# The best detector measured (docs/studies/detector-comparison.md): the plumb-line floor, a ridge on line
# curvature (fit --model plumbline) fitted on fresh pairs of full-size synthetic streets (at 348x128 it sits at the
# mean predictor: the bend it reads is below a pixel there), once on appd and once on bend; each scored on unseen
# streets per frame and per sequence (10 frames under one miscalibration). The frames are made once (their
# calibration file is written last); the streets and draws are the unseen axis of studies.detector. The fit's
# 300 pairs are also its --stats-samples: the mean predictor it is scored against is their label mean. 32 unseen
# sequences: the first 16 miscalibrations alone flatter the floor (docs/studies/detector-comparison.md). ~5 min on 2 cores; 1,200
# pairs gained 0.01-0.03 of the ratios, inside their standard error, for 4x the fitting time. The last lines add the
# bend-field estimator (appdgen.detect, no training; studies.bendfield) on the same unseen streets and draws: a model
# per belief (~12 CPU s each, cached in runs/train/bendfield), 2 processes: ~700 CPU s, ~6 min on 2 idle cores
# uncached (docs/studies/bend-field-detector.md).
FLOOR := runs/train
FLOOR_TRAIN := $(FLOOR)/raw/train
FLOOR_UNSEEN := $(FLOOR)/raw/unseen

$(FLOOR_TRAIN)/calibration.yaml: | $(STAMP)
	rm -rf $(FLOOR_TRAIN)
	$(APPDGEN) synth --frames 300 --seed 101 --out $(FLOOR_TRAIN) --quiet

$(FLOOR_UNSEEN)/calibration.yaml: | $(STAMP)
	rm -rf $(FLOOR_UNSEEN)
	$(APPDGEN) synth --frames 320 --seed 202 --out $(FLOOR_UNSEEN) --quiet

train: $(TRAIN_STAMP) $(FLOOR_TRAIN)/calibration.yaml $(FLOOR_UNSEEN)/calibration.yaml
	for t in appd bend; do \
		rm -rf $(FLOOR)/$$t && mkdir -p $(FLOOR)/$$t && \
		$(PY) -m train fit --online --model plumbline --target $$t --calib $(FLOOR_TRAIN)/calibration.yaml \
			--images $(FLOOR_TRAIN) --interp cubic --steps 10 --batch 30 --val-split none --stats-samples 300 \
			--run $(FLOOR)/$$t --quiet > $(FLOOR)/$$t/fit.json && \
		$(PY) -m train evaluate --ckpt $(FLOOR)/$$t/last.pt --frames $(FLOOR_UNSEEN) --length 10 --threshold 0.5 \
			--json $(FLOOR)/$$t/eval.json > /dev/null || exit 1; \
	done
	@for t in appd bend; do $(PY) -c "import json, sys; d = json.load(open(sys.argv[1])); s = d['sequences']; \
		line = 'make train, %s: on unseen streets MAE / the mean predictor%ss %.2f per frame, '; \
		line += '%.2f per sequence of %d frames (median; %d sequences); details in %s'; \
		print(line % (sys.argv[2], chr(39), d['mae_vs_mean_predictor'], s['median_vs_mean_predictor'], \
		s['length'], s['count'], sys.argv[1]))" $(FLOOR)/$$t/eval.json $$t; done
	@$(PY) -m studies.bendfield --streets $(FLOOR)/raw --axes unseen --lenses "" --no-sequential --jobs 2 \
		--out $(FLOOR)/bendfield --lines > $(FLOOR)/bendfield.txt 2> $(FLOOR)/bendfield.log \
		|| (tail -3 $(FLOOR)/bendfield.log; exit 1)
	@sed 's/^/make train, /' $(FLOOR)/bendfield.txt

# The paper's CNN on the demo shards (the recipe make train had until the detector comparison): within 15 minutes on
# 2 CPU cores (--max-minutes stops early, still validated and checkpointed); it stays at the mean predictor.
train-cnn: $(TRAIN_STAMP)
	@test -f $(DEMO)/shards/labels.parquet || $(MAKE) demo
	rm -rf runs/demo
	$(PY) -m train fit --shards $(DEMO)/shards --split train --run runs/demo --epochs 30 --max-minutes 13 --quiet
	$(PY) -m train evaluate --ckpt runs/demo/best.pt --shards $(DEMO)/shards --split test --threshold 0.5 \
		--json runs/demo/eval.json --plot runs/demo/eval.png

# Learnability check of the whole chain (build → shards → fit → evaluate) with scene variety removed: one synthetic
# frame, its samples split 50/50 into train and test. The CNN only has to read how the frame is warped (~3 min).
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

# The accelerator experiment (docs/studies/accelerator-experiment.md): full-size synthetic KITTI 02 frames, samples, a timed fit of the
# paper's CNN, test MAE vs the mean predictor in one line. Sized to end within 9 minutes on one H200 with 16 cores.
# Sizes are flags of `python -m studies.experiment` (ARGS="--minutes 3 --samples 8000" ...).
paper-scale: $(TRAIN_STAMP)
	$(PY) -m studies.experiment --out runs/paper-scale --overwrite $(ARGS)

# The same code at 348x128 with small sizes: under 3 minutes on 2 CPU cores. Proves the chain, not the quality.
paper-scale-tiny: $(TRAIN_STAMP)
	$(PY) -m studies.experiment --tiny --out runs/paper-scale-tiny --overwrite $(ARGS)

# The detector comparison (docs/studies/detector-comparison.md, issue 23) for the accelerator: every arm (paper CNN at 348x128, patch
# network at 1392x512 on appd, bend and the dense field, the plumb-line floor) on --samples fresh pairs each.
paper-scale-detector: $(TRAIN_STAMP)
	$(PY) -m studies.experiment --detector --out runs/paper-scale-detector --samples 8000 $(ARGS)

# The same comparison on 2 CPU cores (the table in docs/studies/detector-comparison.md), and its few-minute smoke run.
detector: $(TRAIN_STAMP)
	nice -n 10 $(PY) -m studies.detector --images 6000 --frames 300 --sequences 32 --out runs/detector $(ARGS)

detector-tiny: $(TRAIN_STAMP)
	$(PY) -m studies.detector --tiny --out runs/detector-tiny $(ARGS)

# The bend-field estimator (appdgen.detect, issue 32) as an arm of the same comparison: every axis, the sequential
# test and two other lenses (docs/studies/bend-field-detector.md; ~1 h on 2 shared cores, its models cached in
# runs/bendfield/cache); detect-study-tiny in about a minute.
detect-study: $(TRAIN_STAMP)
	nice -n 10 $(PY) -m studies.bendfield --out runs/bendfield $(ARGS)

detect-study-tiny: $(TRAIN_STAMP)
	$(PY) -m studies.bendfield --tiny --out runs/bendfield-tiny $(ARGS)

# Wheels the accelerator machine lacks (its python3 has CUDA torch, OpenCV, pyarrow, click, joblib, pyyaml but not
# webdataset): pure-Python, carried in .whl/ (git-ignored). See docs/studies/accelerator-experiment.md.
device-wheels: $(STAMP)
	$(PY) -m pip download -q --no-deps --only-binary=:all: -d .whl webdataset==1.0.2 braceexpand==0.1.7

bench: $(STAMP)
	$(PY) benchmarks/bench_geometry.py
	$(PY) benchmarks/bench_build.py --samples 120

# Frames/s of appdgen synth for 1 and 2 jobs at full and quarter size, CPU s/frame, identical bytes (~1.5 min).
bench-synth: $(STAMP)
	$(PY) benchmarks/bench_synth.py --frames-full 32 --frames-quarter 128 --trials 2

# Images/s of the cpu (cv2.remap) and device (grid_sample) renderers at 348x128 and 1392x512 against a training step.
bench-render: $(TRAIN_STAMP)
	$(PY) benchmarks/bench_render.py --repeat 5

bench-rss: $(STAMP)
	$(PY) benchmarks/bench_build.py --rss-only

clean:
	rm -rf $(VENV) $(DEMO) runs build dist *.egg-info .pytest_cache .hypothesis
