"""What the install scripts share (install-lpips.py, install-viewer.py): the data folder they
fill, checksums and atomic writes. The trainer finds the same folder by the same rule
(trainer/src/installed.rs)."""

import hashlib
import os


def default_data_dir():
    """`$S3TIR_DATA_HOME`, else `$XDG_DATA_HOME/s3tir`, else `~/.local/share/s3tir`."""
    return os.environ.get("S3TIR_DATA_HOME") or os.path.join(
        os.environ.get("XDG_DATA_HOME") or os.path.expanduser("~/.local/share"), "s3tir")


def sha256(data):
    return hashlib.sha256(data).hexdigest()


def write_atomic(path, data):
    """Writes `path` through `path.partial` and a rename: a failure leaves no half file."""
    tmp = path + ".partial"
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
