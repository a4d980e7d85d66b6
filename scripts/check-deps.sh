#!/usr/bin/env bash
# Enforces the dependency directions of ARCHITECTURE.md with `cargo tree`:
# - no crate depends on a crate of a higher layer (capture < calib < firmware-sim, trainer);
# - slim builds stay slim: capture without OpenCV/Vulkan, calib and trainer without OpenCV
#   when their default features are off, trainer never pulls OpenCV in, and without its
#   defaults (no `session`) neither tokio, MCAP nor a serial port; the simulator never those;
# - plots need no system fonts, and one version of `image` is built;
# - calib's stage folders import one way (the table in ARCHITECTURE.md, "Inside the crates");
# - no import circle between the modules of any crate (scripts/check-imports.py).
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
# The simulator speaks the wire codecs over its own ptys and socket (nix): it needs capture's
# leaf types only, never the recorder's runtime, MCAP or a serial-port crate.
forbid "s3tir-firmware-sim" "$(deps_of s3tir-firmware-sim)" tokio mcap serialport lz4 v4l
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

# calib's stages (ARCHITECTURE.md, "Inside the crates"): which `crate::` paths the library
# files of each folder never use. Comment lines are left out; a brace import spread over
# several lines (`use crate::{…};`) is read as one.
calib_forbid() {  # folder or file under calib/src, forbidden top-level paths...
  local where=$1; shift
  local files
  files=$(find "calib/src/$where" -name '*.rs' ! -path 'calib/src/progress/bars.rs' | sort)
  [ -n "$files" ] || { echo "check-deps: calib/src/$where not found (rule of ARCHITECTURE.md)"; fail=1; return; }
  local hits
  # shellcheck disable=SC2086
  hits=$(awk -v bad="$*" '
    function check(text, line,    n, i, m) {
      n = split(bad, mods, " ")
      for (i = 1; i <= n; i++) {
        m = mods[i]
        if (text ~ ("crate::" m "([^a-z_0-9]|$)") || text ~ ("crate::[{]([^}]*[ ,])?" m "([^a-z_0-9]|$)")) {
          printf "%s:%d: imports crate::%s\n", FILENAME, line, mods[i]
        }
      }
    }
    FNR == 1 { buf = "" }
    /^[[:space:]]*\/\// { next }
    {
      text = $0
      if (buf != "") { buf = buf " " text; if (text ~ /}/) { check(buf, start); buf = "" }; next }
      if (text ~ /crate::[{]/ && text !~ /}/) { buf = text; start = FNR; next }
      check(text, FNR)
    }' $files)
  if [ -n "$hits" ]; then
    while IFS= read -r hit; do
      echo "check-deps: $hit (calib/src/$where never imports: $*; ARCHITECTURE.md)"
    done <<<"$hits"
    fail=1
  fi
}
calib_forbid model detect solve report poses tags progress synth bench progress::bars
calib_forbid detect solve report poses bench progress::bars
calib_forbid solve report poses synth bench progress::bars
calib_forbid report poses synth bench progress::bars
calib_forbid poses detect solve report synth bench progress::bars
calib_forbid error.rs model detect solve report poses synth bench progress::bars
calib_forbid progress model detect solve report poses synth bench progress::bars
calib_forbid tags.rs model detect solve report poses synth bench progress::bars
calib_forbid synth.rs progress::bars
calib_forbid bench.rs progress::bars

# No import circle between the modules of a crate (the script checks itself on a planted one).
python3 scripts/check-imports.py || fail=1

if [ $fail -eq 0 ]; then echo "check-deps: dependency directions, slim builds and calib's module rules OK"; fi
exit $fail
