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

# The demo grows with each stage that lands; every step runs against the simulated rig.
demo: build
	@echo "== Vulkan devices the trainer can use"
	$(BIN)/s3tir-train devices
	@echo "== V4L2 cameras attached to this computer (none on a CI machine)"
	$(BIN)/s3tir-capture list
	@echo "== demo finished; outputs in $(DEMO_DIR)"

lint:
	$(CARGO) fmt --all --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings

# Builds that leave parts out must keep compiling, and dependency directions must hold.
check-features:
	$(CARGO) check -p s3tir-capture --no-default-features
	$(CARGO) check -p s3tir-calib --no-default-features
	$(CARGO) check -p s3tir-trainer --no-default-features
	./scripts/check-deps.sh

test: deps lint check-features
	$(CARGO) test --workspace
