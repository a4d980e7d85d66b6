#!/usr/bin/env python3
"""Pose the real sun-board thermal images into a COLMAP dataset for s3tir-train.

The sun-board set (../shared/data/sun-board) is a sun-heated checkerboard lying on grass,
photographed by a hand-held DJI dual camera from 47 positions: a static real thermal scene
(board + grass). Each thermal image sees the whole board, so the board is a fiducial: its
corners (found by `s3tir-calib detect`) and the thermal intrinsics + distortion from
`s3tir-calib` on the same folder give each view's pose by PnP, in the board's frame (metres,
the board plane is z = 0). This is the "board as fiducial" path done by hand until the poses
stage has it; it needs python3-opencv and numpy (Debian: `apt install python3-opencv`).

Writes DATASET/images/*.png (8-bit grey, undistorted with the calibrated model, so the
cameras are PINHOLE with the calibrated K) and DATASET/sparse/0/{cameras,images,points3D}.txt
(COLMAP text, pixel origin at the corner of the top-left pixel). Seed points: the board plane
(z = 0, the grass around the board lies close to it) sampled where the views see it, thinned
to --points. Prints each view's PnP RMS; views above --max-rms-px are left out.

Usage: sun_board_dataset.py CALIB_BIN CALIBRATION_YAML THERMAL_DIR DATASET [--points N]
"""
import argparse
import glob
import os
import re
import subprocess
import sys

import cv2
import numpy as np


def read_calibration(path):
    text = open(path).read()
    block = text[text.index("  thermal:"):text.index("  rgb:")]
    num = r"([-+0-9.eE]+)"
    size = re.search(r"image_size_px: \[(\d+), (\d+)\]", block)
    k = re.search(rf"intrinsics: {{fx: {num}, fy: {num}, cx: {num}, cy: {num}}}", block)
    d = re.search(rf"distortion: {{k1: {num}, k2: {num}, p1: {num}, p2: {num}, k3: {num}}}", block)
    if not (size and k and d):
        sys.exit(f"{path}: no thermal camera with pinhole+brown-conrady intrinsics")
    fx, fy, cx, cy = map(float, k.groups())
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    dist = np.array(list(map(float, d.groups())))
    board = re.search(r"board: {inner_corners: \[(\d+), (\d+)\], square_mm: ([0-9.]+)}", text)
    cols, rows, square_mm = int(board.group(1)), int(board.group(2)), float(board.group(3))
    return (int(size.group(1)), int(size.group(2))), K, dist, (cols, rows), square_mm / 1000.0


def detect(calib_bin, cols, rows, images):
    out = subprocess.run(
        [calib_bin, "detect", "--inner-corners", f"{cols}x{rows}", *images],
        capture_output=True, text=True)
    corners, name = {}, None
    for line in out.stdout.splitlines():
        m = re.match(r"^(\S+): (\d+) corners", line)
        if m:
            name = m.group(1)
            corners[name] = []
        elif name and line.startswith("  "):
            corners[name].append([float(x) for x in line.split()])
    return {k: np.array(v, dtype=np.float64) for k, v in corners.items() if len(v) == cols * rows}


def quat_from_R(R):
    q = np.empty(4)
    t = np.trace(R)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k]) * 2
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.array(q)
    return q / np.linalg.norm(q) * (1 if q[0] >= 0 else -1)


def write_colmap_text(sparse_dir, w, h, K, images, seeds):
    """COLMAP text model: one PINHOLE camera with OpenCV's K (pixel centres at integers; COLMAP's
    origin is the top-left pixel's corner, so +0.5 on the principal point), `images` as
    (quaternion w x y z, translation, name) of camera-from-world, `seeds` as rows (x, y, z, grey)."""
    with open(os.path.join(sparse_dir, "cameras.txt"), "w") as f:
        f.write("# Camera list: CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n")
        f.write(f"1 PINHOLE {w} {h} {K[0, 0]:.6f} {K[1, 1]:.6f} {K[0, 2] + 0.5:.6f} {K[1, 2] + 0.5:.6f}\n")
    with open(os.path.join(sparse_dir, "images.txt"), "w") as f:
        f.write("# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n")
        for i, (q, t, name) in enumerate(images):
            f.write(f"{i + 1} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f} {t[0]:.6f} {t[1]:.6f} {t[2]:.6f} 1 {name}\n\n")
    with open(os.path.join(sparse_dir, "points3D.txt"), "w") as f:
        f.write("# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]\n")
        for i, (x, y, z, v) in enumerate(seeds):
            g = int(v)
            f.write(f"{i + 1} {x:.5f} {y:.5f} {z:.5f} {g} {g} {g} 0\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("calib_bin")
    ap.add_argument("calibration")
    ap.add_argument("thermal_dir")
    ap.add_argument("dataset")
    ap.add_argument("--points", type=int, default=8000)
    ap.add_argument("--max-rms-px", type=float, default=1.5)
    a = ap.parse_args()
    (w, h), K, dist, (cols, rows), square = read_calibration(a.calibration)
    images = sorted(glob.glob(os.path.join(a.thermal_dir, "*.jpg")) + glob.glob(os.path.join(a.thermal_dir, "*.JPG")))
    found = detect(a.calib_bin, cols, rows, images)
    obj = np.array([[c * square, r * square, 0.0] for r in range(rows) for c in range(cols)])
    os.makedirs(os.path.join(a.dataset, "images"), exist_ok=False)
    os.makedirs(os.path.join(a.dataset, "sparse", "0"))
    mapx, mapy = cv2.initUndistortRectifyMap(K, dist, None, K, (w, h), cv2.CV_32FC1)
    poses, prev_centre = [], None
    for path in images:
        name = os.path.basename(path)
        pts = found.get(path)
        if pts is None:
            print(f"{name}: no board, left out")
            continue
        # The corner order has a 180° ambiguity: take the one whose camera centre is closest to
        # the previous view's (the camera moves smoothly between shots).
        best = None
        for cand in (pts, pts[::-1].copy()):
            ok, rvec, tvec = cv2.solvePnP(obj, cand, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
            R, _ = cv2.Rodrigues(rvec)
            centre = (-R.T @ tvec).ravel()
            proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
            rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - cand) ** 2, axis=1))))
            above = centre[2] < 0  # the board's z points into the ground; cameras above it
            score = (0 if above else 1, 0 if prev_centre is None else np.linalg.norm(centre - prev_centre))
            if best is None or score < best[0]:
                best = (score, R, tvec.ravel(), centre, rms)
        _, R, t, centre, rms = best
        if rms > a.max_rms_px:
            print(f"{name}: PnP RMS {rms:.2f} px > {a.max_rms_px}, left out")
            continue
        prev_centre = centre
        grey = cv2.cvtColor(cv2.imread(path), cv2.COLOR_BGR2GRAY)
        und = cv2.remap(grey, mapx, mapy, cv2.INTER_LINEAR)
        stem = os.path.splitext(name)[0] + ".png"
        cv2.imwrite(os.path.join(a.dataset, "images", stem), und)
        poses.append((stem, R, t, centre, rms, und))
        print(f"{name}: PnP RMS {rms:.3f} px, camera at ({centre[0]:.2f}, {centre[1]:.2f}, {centre[2]:.2f}) m")
    if len(poses) < 3:
        sys.exit("fewer than 3 posed views")
    # Seeds: the plane z = 0 seen through each view (a grid of pixels), thinned on a grid.
    rng = np.random.default_rng(0)
    Kinv = np.linalg.inv(K)
    seeds = []
    for stem, R, t, centre, _, img in poses:
        us, vs = np.meshgrid(np.arange(4, w, 8), np.arange(4, h, 8))
        rays = Kinv @ np.stack([us.ravel(), vs.ravel(), np.ones(us.size)])
        dirs = R.T @ rays
        s = -centre[2] / dirs[2]
        ok = s > 0
        p = centre[:, None] + dirs[:, ok] * s[ok]
        vals = img[vs.ravel()[ok], us.ravel()[ok]]
        seeds.append(np.vstack([p, vals[None, :]]).T)
    seeds = np.concatenate(seeds)
    if len(seeds) > a.points:
        seeds = seeds[rng.choice(len(seeds), a.points, replace=False)]
    write_colmap_text(os.path.join(a.dataset, "sparse", "0"), w, h, K,
                      [(quat_from_R(R), t, stem) for stem, R, t, *_rest in poses], seeds)
    rms = [p[4] for p in poses]
    print(f"{len(poses)} of {len(images)} views posed (PnP RMS median {np.median(rms):.3f} px, max {max(rms):.3f} px); {len(seeds)} seed points; written to {a.dataset}")


if __name__ == "__main__":
    main()
