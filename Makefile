# s3tir: two commands. `make demo` runs the whole chain on the simulated rig; `make test` runs the
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

# The whole chain on the simulated rig, as a user runs it on a real one: calibrate the rig,
# record a walk around a scene with the calibration attached, pose the walk (COLMAP on the RGB
# keyframes, metric scale from the room's AprilTags), train S3-TIR on the posed thermal views
# and evaluate the held-out ones. Every
# device is s3tir-firmware-sim; outputs in DEMO_DIR (walk.mcap, walk-dataset/, walk-run/).
DEMO_ITERS ?= 300
DEMO_WALK_S ?= 20
DEMO_BOARD_S ?= 40
demo: build
	@mkdir -p $(DEMO_DIR)
	@# A previous demo's outputs would be refused (the poses stage and the trainer never overwrite).
	@for d in board.mcap board-truth walk.mcap walk-truth walk-dataset walk-dataset.partial walk-run calibration joint-scene joint-run; do \
	  if [ -e $(DEMO_DIR)/$$d ]; then echo "   (replacing the previous demo's $$d)"; rm -rf $(DEMO_DIR)/$$d; fi; done
	@echo "== 1/9 Vulkan devices the trainer can use"
	$(BIN)/s3tir-train devices
	@echo "== 2/9 Calibrate the rig: record $(DEMO_BOARD_S) s of the emissivity board waved in front of it"
	@echo "        (Lepton 3.5 + RGB), then one joint thermal + RGB solve from that session"
	$(BIN)/s3tir-capture --device sim:lepton35 --rgb sim --walk board --duration-s $(DEMO_BOARD_S) \
	  --out $(DEMO_DIR)/board.mcap
	$(BIN)/s3tir-calib $(DEMO_DIR)/board.mcap --board $(DEMO_DIR)/board-truth/board.toml \
	  --out $(DEMO_DIR)/calibration/calibration.yaml \
	  --report $(DEMO_DIR)/calibration/report --summary-json $(DEMO_DIR)/calibration/summary.json
	@echo "== 3/9 Record a $(DEMO_WALK_S) s hand-held walk around the simulated scene (calibration attached;"
	@echo "        the simulator renders every frame, so this takes longer than $(DEMO_WALK_S) s)"
	$(BIN)/s3tir-capture --device sim:lepton35 --rgb sim --walk handheld --duration-s $(DEMO_WALK_S) \
	  --calibration $(DEMO_DIR)/calibration/calibration.yaml --out $(DEMO_DIR)/walk.mcap
	$(BIN)/s3tir-capture info $(DEMO_DIR)/walk.mcap
	@echo "== 4/9 Pose the walk: COLMAP (CPU) on the RGB keyframes, thermal poses from the calibrated extrinsic;"
	@echo "        the room's AprilTag map (walk-truth/tags.toml, as a user would measure it) gives the metric"
	@echo "        scale and checks COLMAP's model against the tags' own poses"
	$(BIN)/s3tir-capture export $(DEMO_DIR)/walk.mcap --dataset $(DEMO_DIR)/walk-dataset \
	  --tags $(DEMO_DIR)/walk-truth/tags.toml --no-tag-poses
	@echo "== 5/9 Train S3-TIR on the posed thermal views ($(DEMO_ITERS) iterations on the backend --backend auto picks; short"
	@echo "        warm-up and a raised beta learning rate so shape and bands act within a demo's budget)"
	$(BIN)/s3tir-train $(DEMO_DIR)/walk-dataset --out $(DEMO_DIR)/walk-run --iters $(DEMO_ITERS) \
	  --warmup 100 --budget 3000 --beta-lr 0.05 --eval-every-s 5
	@echo "== 6/9 Evaluate the held-out views (never seen by the poses or the training)"
	$(BIN)/s3tir-train eval $(DEMO_DIR)/walk-run
	@echo "== 7/9 Joint RGB + thermal (TGA-GS): a low-light RGB camera at 4x the thermal resolution, one"
	@echo "        model with a thermal and a colour head, its thermal rendered at the RGB resolution and"
	@echo "        scored against the simulator's truth (and against bicubic upsampling of the thermal input)"
	$(BIN)/s3tir-firmware-sim scene --out $(DEMO_DIR)/joint-scene --rgb-scale 4 --width 32 --height 24 \
	  --views 16 --low-light
	$(BIN)/s3tir-train $(DEMO_DIR)/joint-scene --out $(DEMO_DIR)/joint-run --iters 600 --warmup 150 \
	  --budget 3000 --eval-every-s 1e9
	$(BIN)/s3tir-train eval $(DEMO_DIR)/joint-run --truth
	@echo "== 8/9 Thermal meshes: the walk's model and the joint model fused into surfaces with a temperature"
	@echo "        per vertex (PLY for MeshLab / Blender / CloudCompare); the joint one scored against the truth"
	$(BIN)/s3tir-train mesh $(DEMO_DIR)/walk-run --out $(DEMO_DIR)/walk-run/mesh.ply
	$(BIN)/s3tir-train mesh $(DEMO_DIR)/joint-run --out $(DEMO_DIR)/joint-run/mesh.ply --truth
	@echo "== 9/9 Look at the result: every run wrote report.html (recorded | rendered | error in kelvin and"
	@echo "        degrees C); a fly-through around the walk's model (MP4 with ffmpeg installed, else GIF)"
	$(BIN)/s3tir-train render $(DEMO_DIR)/walk-run --path orbit --frames 90 --out $(DEMO_DIR)/walk-run/flight
	@echo "== demo finished in $(DEMO_DIR): walk.mcap (+ walk-truth/), walk-dataset/ (poses.json says what"
	@echo "   was kept and why), walk-run/ (eval.json, error-vs-time plots, renders), calibration/,"
	@echo "   joint-run/ (renders_sr/: thermal at the RGB resolution), walk-run/mesh.ply and joint-run/mesh.ply"
	@echo "   (kelvin per vertex; *_thermal.ply coloured for viewers that show only RGB)"
	@echo "== look at the result: open these in a browser (self-contained pages; renders/*_ironbow.png beside"
	@echo "   the 16-bit renders carry their kelvin range in the file):"
	@echo "   $(DEMO_DIR)/walk-run/report.html"
	@echo "   $(DEMO_DIR)/joint-run/report.html"
	@echo "   $(DEMO_DIR)/calibration/report/report.html"
	@echo "   and the fly-through: $(DEMO_DIR)/walk-run/flight/ (flight.mp4 or flight.gif, frames beside it)"
	@echo "== the 3-D viewer (orbit the thermal mesh, read any point's temperature in K and degrees C):"
	@echo "   $(BIN)/s3tir-train view $(DEMO_DIR)/walk-run    then open http://127.0.0.1:8765/ (Ctrl-C stops it)"

lint:
	$(CARGO) fmt --all --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings

# Builds that leave parts out must keep compiling, and dependency directions must hold.
check-features:
	$(CARGO) check -p s3tir-capture --no-default-features
	$(CARGO) check -p s3tir-capture --no-default-features --features session
	$(CARGO) check -p s3tir-capture --features nokhwa
	$(CARGO) check -p s3tir-calib --no-default-features
	$(CARGO) check -p s3tir-trainer --no-default-features
	$(CARGO) check -p s3tir-trainer --no-default-features --features session
	./scripts/check-deps.sh

# What this project's CI machine has (scripts/install-deps.sh installs spirv-tools, systemd,
# chromium, ffmpeg, the LPIPS weights with their reference pairs and the viewer's three.js; the
# kernel gives /dev/full): a test that would skip for lack of one of these fails instead
# (capture/src/skip.rs). No camera is attached, so `camera` skips visibly.
S3TIR_REQUIRE ?= spirv-val,dev-full,systemd-analyze,lpips,chromium,viewer-assets,ffmpeg
export S3TIR_REQUIRE

test: deps lint check-features
	$(CARGO) test --workspace
