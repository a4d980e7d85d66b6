# s3tir: two commands. `make demo` runs the pipeline on the simulated rig; `make test` runs the
# whole suite (what CI runs). Both install missing system packages first.

# Build cache outside the clone: rebuilds on a reused machine take seconds. Override freely.
export CARGO_TARGET_DIR ?= $(HOME)/.cache/s3tir-target
CARGO ?= cargo
DEMO_DIR ?= $(CURDIR)/demo-out
BIN := $(CARGO_TARGET_DIR)/debug

.PHONY: demo test deps build lint check-features

deps:
	./scripts/install-deps.sh

build: deps
	$(CARGO) build --workspace --bins

# The whole pipeline on the simulated rig: capture a session, calibrate the board set, train and
# evaluate a small S3-TIR model. Every step runs against s3tir-firmware-sim; outputs in DEMO_DIR.
DEMO_ITERS ?= 300
demo: build
	@mkdir -p $(DEMO_DIR)
	@echo "== 1/5 Vulkan devices the trainer can use"
	$(BIN)/s3tir-train devices
	@echo "== 2/5 Record 5 s from the simulated rig (Lepton 3.5 + RGB): starts s3tir-firmware-sim, stops it at exit"
	$(BIN)/s3tir-capture --device sim:lepton35 --rgb sim --out $(DEMO_DIR)/session.mcap --duration 5
	$(BIN)/s3tir-capture info $(DEMO_DIR)/session.mcap
	@echo "== 3/5 Calibrate: the simulated emissivity-board set (30 views), joint thermal + RGB solve"
	$(BIN)/s3tir-firmware-sim board --out $(DEMO_DIR)/board --views 30
	$(BIN)/s3tir-calib $(DEMO_DIR)/board --out $(DEMO_DIR)/calibration/calibration.yaml \
	  --report $(DEMO_DIR)/calibration/report --summary-json $(DEMO_DIR)/calibration/summary.json
	@echo "== 4/5 Train S3-TIR on the simulated thermal scene ($(DEMO_ITERS) iterations, CPU backend;"
	@echo "        short warm-up and a raised beta learning rate so shape and bands act within a demo's budget)"
	$(BIN)/s3tir-firmware-sim scene --out $(DEMO_DIR)/scene
	@# A previous demo's run would make s3tir-train refuse the folder (it never overwrites a run).
	@if [ -e $(DEMO_DIR)/run ]; then echo "   (replacing the previous demo run in $(DEMO_DIR)/run)"; rm -rf $(DEMO_DIR)/run; fi
	$(BIN)/s3tir-train $(DEMO_DIR)/scene --out $(DEMO_DIR)/run --iters $(DEMO_ITERS) \
	  --warmup 100 --budget 1000 --beta-lr 0.05 --eval-every-s 5
	@echo "== 5/5 Evaluate the held-out views"
	$(BIN)/s3tir-train eval $(DEMO_DIR)/run
	@echo "== demo finished: session, calibration, trained model, plots and renders are in $(DEMO_DIR)"

lint:
	$(CARGO) fmt --all --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings

# Builds that leave parts out must keep compiling, and dependency directions must hold.
check-features:
	$(CARGO) check -p s3tir-capture --no-default-features
	$(CARGO) check -p s3tir-capture --features nokhwa
	$(CARGO) check -p s3tir-calib --no-default-features
	$(CARGO) check -p s3tir-trainer --no-default-features
	./scripts/check-deps.sh

test: deps lint check-features
	$(CARGO) test --workspace
