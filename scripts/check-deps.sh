#!/usr/bin/env bash
# Enforces the dependency directions of ARCHITECTURE.md with `cargo tree`:
# - no crate depends on a crate of a higher layer (capture < calib < firmware-sim, trainer);
# - slim builds stay slim: capture without OpenCV/Vulkan, calib and trainer without OpenCV
#   when their default features are off, trainer never pulls OpenCV in, and without its
#   defaults (no `session`) neither tokio, MCAP nor a serial port;
# - plots need no system fonts, and one version of `image` is built.
set -euo pipefail
cd "$(dirname "$0")/.."
fail=0

deps_of() {  # package, extra cargo-tree args...
  local pkg=$1; shift
  cargo tree -q -e normal -p "$pkg" --prefix none "$@" | awk '{print $1}' | sort -u
}

forbid() {  # label, list, forbidden crate names...
  local label=$1 list=$2; shift 2
  for bad in "$@"; do
    if grep -qx "$bad" <<<"$list"; then
      echo "check-deps: $label depends on $bad (forbidden by ARCHITECTURE.md)"; fail=1
    fi
  done
}

forbid "s3tir-capture" "$(deps_of s3tir-capture)" s3tir-calib s3tir-trainer s3tir-firmware-sim opencv ash
forbid "s3tir-capture --no-default-features" "$(deps_of s3tir-capture --no-default-features)" tokio mcap serialport nix v4l lz4
forbid "s3tir-capture --no-default-features --features session" "$(deps_of s3tir-capture --no-default-features --features session)" tokio serialport nix v4l
forbid "s3tir-calib" "$(deps_of s3tir-calib)" s3tir-trainer s3tir-firmware-sim ash
forbid "s3tir-calib --no-default-features" "$(deps_of s3tir-calib --no-default-features)" opencv
forbid "s3tir-trainer" "$(deps_of s3tir-trainer)" s3tir-firmware-sim opencv
forbid "s3tir-trainer --no-default-features" "$(deps_of s3tir-trainer --no-default-features)" ash gpu-allocator opencv tokio mcap serialport
forbid "s3tir-firmware-sim" "$(deps_of s3tir-firmware-sim)" s3tir-trainer opencv ash
# Plots draw text from the bundled font (s3tir_calib::plot): no system font lookup on a rig.
forbid "s3tir-calib" "$(deps_of s3tir-calib)" font-kit yeslogic-fontconfig-sys
forbid "s3tir-trainer" "$(deps_of s3tir-trainer)" font-kit yeslogic-fontconfig-sys

# One version of the image codec crate (plotters' own PNG encoder pinned a second one).
for pkg in s3tir-calib s3tir-trainer; do
  versions=$(cargo tree -q -e normal -p "$pkg" --prefix none | awk '$1 == "image" {print $2}' | sort -u)
  if [ "$(wc -l <<<"$versions")" -gt 1 ]; then
    echo "check-deps: $pkg pulls several versions of image: $(tr '\n' ' ' <<<"$versions")"; fail=1
  fi
done

if [ $fail -eq 0 ]; then echo "check-deps: dependency directions and slim builds OK"; fi
exit $fail
