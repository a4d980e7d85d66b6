#!/usr/bin/env python3
"""Installs the 3-D viewer's renderer (three.js from the npm registry) for `s3tir-train view`.

The viewer's page (trainer/src/look/view/page/) is shipped inside the binary; the WebGL renderer
it draws with is three.js, vendored here once at install time (`install-deps.sh`), never fetched
from a CDN by the page:

1. Download the npm registry's tarball of `three` 0.187.0 and check its SHA-256.
2. Write the four modules the page imports (the core build, the module build, OrbitControls and
   PLYLoader) and three.js's MIT licence to `DATA/viewer/three-0.187.0/`. The trainer checks
   each file's SHA-256 before serving it (trainer/src/look/view/assets.rs holds the same values).

DATA is `$S3TIR_DATA_HOME`, else `$XDG_DATA_HOME/s3tir`, else `~/.local/share/s3tir`.
Idempotent: files already present with the right checksums are kept.

Usage: install-viewer.py [--data-dir DIR] [--from-file three-0.187.0.tgz]
"""

import argparse
import os
import sys
import tarfile
import tempfile
import urllib.request

from install_common import default_data_dir, sha256, write_atomic

VERSION = "0.187.0"
TARBALL = f"three-{VERSION}.tgz"
URL = f"https://registry.npmjs.org/three/-/{TARBALL}"
TARBALL_SHA256 = "ff540832ded0cfe919764d24a3d88f3e2a05f23303f876423e4f893841e90728"
# member of the tarball -> (file under DATA/viewer/three-VERSION/, SHA-256)
FILES = {
    "package/build/three.module.js": (
        "three.module.js", "104f56145899722094556490d787aae0617cc2fc3382f31df02d724ea1aee341"),
    "package/build/three.core.js": (
        "three.core.js", "613e370f76638fdef83926642bf256dc9615684922de1ce1f63a8583e5d78578"),
    "package/examples/jsm/controls/OrbitControls.js": (
        "OrbitControls.js", "e7fca2fe9e7670a828af9b28084669a5909445b7f36f1f26cee9bf8f2961c32c"),
    "package/examples/jsm/loaders/PLYLoader.js": (
        "PLYLoader.js", "751ff866f793ba1fc9181425748d88b7f9234c6e9983386fdaf2e664221340f2"),
    "package/LICENSE": (
        "LICENSE", "8b378ebe60e2fe500158cb0ac71cb5e8b7d92953c2abcc63a0eb90499653b5bc"),
}


def file_ok(path, digest):
    if not os.path.exists(path):
        return False
    with open(path, "rb") as f:
        return sha256(f.read()) == digest


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    default = default_data_dir()
    ap.add_argument("--data-dir", default=default, help=f"where to install (default {default})")
    ap.add_argument("--from-file", help=f"an already downloaded {TARBALL}")
    args = ap.parse_args()
    dest = os.path.join(args.data_dir, "viewer", f"three-{VERSION}")
    if all(file_ok(os.path.join(dest, name), digest) for name, digest in FILES.values()):
        print(f"install-viewer: three.js {VERSION} present in {dest}")
        return
    if args.from_file:
        with open(args.from_file, "rb") as f:
            data = f.read()
    else:
        try:
            with urllib.request.urlopen(URL, timeout=120) as r:
                data = r.read()
        except OSError as e:
            sys.exit(f"install-viewer: could not download {URL}: {e} "
                     "(s3tir-train view needs it; run this script again when the npm registry "
                     "is reachable)")
    if sha256(data) != TARBALL_SHA256:
        sys.exit(f"install-viewer: {TARBALL} has SHA-256 {sha256(data)}, expected {TARBALL_SHA256}")
    os.makedirs(dest, exist_ok=True)
    with tempfile.TemporaryDirectory() as work:
        path = os.path.join(work, TARBALL)
        with open(path, "wb") as f:
            f.write(data)
        with tarfile.open(path, "r:gz") as tar:
            for member, (name, digest) in FILES.items():
                body = tar.extractfile(member).read()
                if sha256(body) != digest:
                    sys.exit(f"install-viewer: {member} has SHA-256 {sha256(body)}, expected {digest}")
                write_atomic(os.path.join(dest, name), body)
    print(f"install-viewer: three.js {VERSION} (MIT licence beside it) installed in {dest}")


if __name__ == "__main__":
    main()
