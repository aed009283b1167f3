# Two commands do all set-up on a fresh machine: `make demo` (the main job on embedded data) and `make test`.
# The research targets (studies, the detector comparison, the accelerator experiment) are in studies.mk.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
APPDGEN := $(VENV)/bin/appdgen
STAMP := $(VENV)/.installed
TRAIN_STAMP := $(VENV)/.installed-train
DEMO := demo
# The CPU build of torch (an unpinned torch pulls a multi-GB CUDA build).
TORCH := torch==2.13.0

.PHONY: demo test test-core test-slow test-heavy train train-cnn bench bench-synth bench-render bench-rss clean

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

# Lint (ruff, configured in pyproject.toml), then every check a commit needs, with the trainer's tests (torch, the
# CPU build: see TORCH) and the recordings' (the ros and video extras). The `slow` and `heavy` tests are left out
# (make test-slow, make test-heavy); docs/performance.md says how long it takes.
test: $(TRAIN_STAMP)
	$(PY) -m ruff check -q .
	$(PY) -m pytest -q -m "not slow"

# The generator alone: make test without torch (the trainer's tests skip). CI keeps `make test`.
test-core: $(STAMP)
	$(PY) -m pytest -q -m "not slow"

# Checks not needed on every commit, left out of make test (a plain `pytest` runs them too): label flatness at
# many draws, random kills, the renamed layout, the studies' and the plumb-line fit's end-to-end runs, the device
# renderer on CPU.
test-slow: $(TRAIN_STAMP)
	$(PY) -m pytest -q -m slow

# Minutes-long checks, run only when asked for (tests/conftest.py): the 20,000-draw label uniformity per lens model.
test-heavy: $(TRAIN_STAMP)
	$(PY) -m pytest -q -m heavy

# The plumb-line floor (train/plumbline.py: a ridge on line curvature, fit --model plumbline), fitted on fresh pairs
# of 300 full-size synthetic streets, once on appd and once on bend, each scored on 320 unseen streets per frame and
# per sequence (10 frames under one miscalibration, evaluate --frames); then the bend-field estimator (appdgen
# detect, no training; studies.bendfield) on the same unseen streets and draws, its models cached in
# runs/train/bendfield. The fit's pairs are its --stats-samples: the mean predictor it is scored against is their
# label mean. docs/training.md gives its figures and time.
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
		$(PY) -m train evaluate --ckpt $(FLOOR)/$$t/last.pt --frames $(FLOOR_UNSEEN) --length 10 \
			--json $(FLOOR)/$$t/eval.json > /dev/null || exit 1; \
	done
	@$(PY) -m studies.bendfield --streets $(FLOOR)/raw --axes unseen --lenses "" --no-sequential --jobs 2 \
		--out $(FLOOR)/bendfield --lines > $(FLOOR)/bendfield.txt 2> $(FLOOR)/bendfield.log \
		|| (tail -3 $(FLOOR)/bendfield.log; exit 1)
	@sed 's/^/make train, /' $(FLOOR)/bendfield.txt

# The paper's CNN on the demo shards, within 15 minutes on 2 CPU cores (--max-minutes stops early, still validated
# and checkpointed).
train-cnn: $(TRAIN_STAMP)
	@test -f $(DEMO)/shards/labels.parquet || $(MAKE) demo
	rm -rf runs/demo
	$(PY) -m train fit --shards $(DEMO)/shards --split train --run runs/demo --epochs 30 --max-minutes 13 --quiet
	$(PY) -m train evaluate --ckpt runs/demo/best.pt --shards $(DEMO)/shards --split test \
		--json runs/demo/eval.json --plot runs/demo/eval.png

# Times of the geometry (crop, maps, APPD) and of a small build.
bench: $(STAMP)
	$(PY) benchmarks/bench_geometry.py
	$(PY) benchmarks/bench_build.py --samples 120

# Frames/s of appdgen synth for 1 and 2 jobs at full and quarter size, CPU s/frame, identical bytes.
bench-synth: $(STAMP)
	$(PY) benchmarks/bench_synth.py --frames-full 32 --frames-quarter 128 --trials 2

# Images/s of the cpu (cv2.remap) and device (grid_sample) renderers at 348x128 and 1392x512 against a training step.
bench-render: $(TRAIN_STAMP)
	$(PY) benchmarks/bench_render.py --repeat 5

# Peak memory of a build.
bench-rss: $(STAMP)
	$(PY) benchmarks/bench_build.py --rss-only

# Remove the virtual environment, the demo, the runs and the build and test caches.
clean:
	rm -rf $(VENV) $(DEMO) runs build dist *.egg-info .pytest_cache .hypothesis

include studies.mk
