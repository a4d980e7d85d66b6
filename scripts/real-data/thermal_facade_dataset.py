#!/usr/bin/env python3
"""Pose the real thermal-facade images into a COLMAP dataset for s3tir-train.

The thermal-facade set (../shared/data/thermal-facade) is 93 thermal JPEGs of a brick facade
shot by a DJI Mavic 2 Enterprise Dual flying a lawn-mower pattern: eight rows 0.6-9.2 m above
take-off, ~1.1 m between shots, the gimbal level and facing the wall from ~3 m. COLMAP 3.8 does
not pose it (see README.md): a planar wall seen by cameras that only translate is the degenerate
case of two-view geometry, the 160x120 core's images are soft, and the windows repeat.

This script uses what the scene is instead: a plane, photographed with known orientation.
1. Priors from each JPEG's DJI XMP block: GPS, barometric relative altitude, gimbal yaw/pitch/roll.
2. Every image undistorted (one radial term, --k1) and rotated by its gimbal angles into one
   reference orientation, so that the wall moves between neighbouring shots by a translation.
3. Pairs of shots closer than --pair-m: 64-px patches of one matched by normalised
   cross-correlation in the other, searched within --search-px of the shift the GPS predicts
   (which resolves the repeated windows); a pair is kept when >= 3 patches agree within 4 px.
4. A least-squares solve of each shot's in-plane offset from the pair shifts (GPS as a weak
   prior) drops pairs that disagree with the rest (mismatched windows).
5. Bundle adjustment of every camera's centre and rotation and every matched patch's 3D point,
   with the points held near one plane (normal and distance estimated, --plane-sigma-m, robust
   so windows and the eave may leave it) and priors on GPS (1.5 m), altitude (0.15 m) and gimbal
   angles (1.5 deg). The reprojection error it prints is the posing's figure of merit.
Writes DATASET/images/*.png (8-bit grey, undistorted: the camera is PINHOLE), DATASET/sparse/0/
{cameras,images,points3D}.txt (COLMAP text, local east-north-up metres from the first shot) and
DATASET/poses.json (the figures). Seed points: the fitted wall plane seen through each view,
with the image's grey value, thinned to --points. Shots no pair reaches are left out (named).

Needs python3-opencv and numpy (Debian: `apt install python3-opencv`); ~4 min on 2 cores.
Usage: thermal_facade_dataset.py IMAGES_DIR DATASET [--points N] [--k1 K1] [--focal-px F]
       [--px-per-m S] [--pair-m M] [--search-px R] [--plane-sigma-m S] [--iters N]
"""
import argparse
import glob
import json
import math
import os
import re
import sys

import cv2
import numpy as np

from sun_board_dataset import quat_from_R, write_colmap_text

PATCH = 32  # half size of the matched patches, px


def read_xmp(path):
    """GPS (deg), relative altitude (m) and gimbal angles (deg) from a DJI JPEG's XMP block."""
    text = open(path, "rb").read().decode("latin1")

    def field(name):
        m = re.search(r'drone-dji:' + name + r'="([-+0-9.]+)"', text)
        if m is None:
            sys.exit(f"{path}: no drone-dji:{name} in its XMP block (not a DJI image?)")
        return float(m.group(1))

    return {k: field(k) for k in ("GpsLatitude", "GpsLongitude", "RelativeAltitude", "GimbalYawDegree",
                                  "GimbalPitchDegree", "GimbalRollDegree")}


def world_from_cam(yaw_deg, pitch_deg, roll_deg):
    """Rotation world (east, north, up) <- camera (x right, y down, z forward) for a gimbal
    heading `yaw` (clockwise from north), `pitch` (up positive) and `roll`."""
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    fwd = np.array([math.sin(y) * math.cos(p), math.cos(y) * math.cos(p), math.sin(p)])
    right = np.array([math.cos(y), -math.sin(y), 0.0])
    down = np.cross(fwd, right)
    cr, sr = math.cos(r), math.sin(r)
    return np.stack([right, down, fwd], 1) @ np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])


def skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def exp_so3(w):
    th = np.linalg.norm(w)
    if th < 1e-12:
        return np.eye(3) + skew(w)
    k = skew(w / th)
    return np.eye(3) + math.sin(th) * k + (1 - math.cos(th)) * k @ k


def register_pair(a, b, t0, search):
    """Patches of `a` found in `b` near the predicted shift `t0` (px): list of (centre in a,
    centre in b) for the patches that agree, or None."""
    h, w = a.shape
    found = []
    for py in range(16, h - 16 - 2 * PATCH, 32):
        for px in range(16, w - 16 - 2 * PATCH, 32):
            tpl = a[py:py + 2 * PATCH, px:px + 2 * PATCH]
            if tpl.std() < 6:  # flat sky or wall: no position in it
                continue
            qx, qy = px + t0[0], py + t0[1]
            x0, y0 = max(0, int(qx - search)), max(0, int(qy - search))
            x1, y1 = min(w, int(qx + 2 * PATCH + search)), min(h, int(qy + 2 * PATCH + search))
            if x1 - x0 < 2 * PATCH + 8 or y1 - y0 < 2 * PATCH + 8:
                continue
            res = cv2.matchTemplate(b[y0:y1, x0:x1], tpl, cv2.TM_CCOEFF_NORMED)
            _, peak, _, loc = cv2.minMaxLoc(res)
            if peak >= 0.5:
                found.append((px + PATCH, py + PATCH, x0 + loc[0] + PATCH, y0 + loc[1] + PATCH))
    if len(found) < 3:
        return None
    f = np.array(found, np.float64)
    d = f[:, 2:4] - f[:, 0:2]
    agree = np.linalg.norm(d - np.median(d, 0), axis=1) < 4.0
    if agree.sum() < 3:
        return None
    return f[agree]


def solve_offsets(n, pairs, g, scale, gps_sigma_m):
    """In-plane offsets (px) of every shot from the pair shifts, GPS `g` (m) as a weak prior;
    returns the offsets and the pairs that agree with them."""
    active = dict(pairs)
    for _ in range(4):
        rows, rhs, wts = [], [], []
        for (i, j), m in active.items():
            t = (m[:, 2:4] - m[:, 0:2]).mean(0)
            for a in range(2):
                row = np.zeros(2 * n)
                row[2 * j + a], row[2 * i + a] = 1, -1
                rows.append(row), rhs.append(-t[a]), wts.append(0.5)
        for i in range(n):
            for a in range(2):
                row = np.zeros(2 * n)
                row[2 * i + a] = 1
                rows.append(row), rhs.append(scale * g[i, a]), wts.append(1 / (scale * gps_sigma_m))
        wv = np.array(wts)
        x = np.linalg.lstsq(np.array(rows) * wv[:, None], np.array(rhs) * wv, rcond=None)[0]
        p = x.reshape(n, 2)
        res = {k: np.linalg.norm(p[k[1]] - p[k[0]] + (m[:, 2:4] - m[:, 0:2]).mean(0)) for k, m in pairs.items()}
        thr = max(6.0, 4 * float(np.median(list(res.values()))))
        active = {k: m for k, m in pairs.items() if res[k] < thr}
    return p, active


def bundle_adjust(K, rot0, centre0, obs_cam, obs_pt, uv, points, plane, gps, alt, sig, iters):
    """Levenberg-Marquardt over camera centres, rotation corrections, points and the plane
    (normal tilt about the reference right/down axes, distance); robust (Huber) residuals."""
    n, m = len(centre0), len(points)
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    rot, centre, pts = [r.copy() for r in rot0], centre0.copy(), points.copy()
    fwd, ea, eb = plane["fwd"], plane["right"], plane["down"]
    pl = np.array([0.0, 0.0, plane["d"]])
    nobs = len(obs_cam)
    N = 6 * n + 3 * m + 3
    lam = 1e-3

    def normal(q):
        v = fwd + q[0] * ea + q[1] * eb
        return v / np.linalg.norm(v)

    def residuals(rot, centre, pts):
        R = np.array(rot)
        y = np.einsum("nji,nj->ni", R[obs_cam], pts[obs_pt] - centre[obs_cam])
        return np.c_[f * y[:, 0] / y[:, 2] + cx, f * y[:, 1] / y[:, 2] + cy] - uv, y

    for _ in range(iters):
        r, y = residuals(rot, centre, pts)
        e = np.linalg.norm(r, axis=1)
        w = np.sqrt(np.where(e < 2.0, 1.0, 2.0 / np.maximum(e, 1e-9)))
        J = np.zeros((2 * nobs + 6 * n + m, N))
        res = np.zeros(J.shape[0])
        z = y[:, 2]
        dudy = np.zeros((nobs, 2, 3))
        dudy[:, 0, 0], dudy[:, 0, 2] = f / z, -f * y[:, 0] / z**2
        dudy[:, 1, 1], dudy[:, 1, 2] = f / z, -f * y[:, 1] / z**2
        Rt = np.array(rot)[obs_cam].transpose(0, 2, 1)
        skews = np.zeros((nobs, 3, 3))
        skews[:, 0, 1], skews[:, 0, 2], skews[:, 1, 2] = -y[:, 2], y[:, 1], -y[:, 0]
        skews[:, 1, 0], skews[:, 2, 0], skews[:, 2, 1] = y[:, 2], -y[:, 1], y[:, 0]
        blocks = [(-dudy @ Rt, 6 * obs_cam), (dudy @ skews, 6 * obs_cam + 3), (dudy @ Rt, 6 * n + 3 * obs_pt)]
        ridx = np.arange(nobs)
        for jac, col in blocks:
            for a in range(2):
                for c in range(3):
                    J[2 * ridx + a, col + c] = jac[:, a, c] * w
        res[0:2 * nobs:2], res[1:2 * nobs:2] = r[:, 0] * w, r[:, 1] * w
        b0 = 2 * nobs
        for c in range(n):
            for a, (val, s) in enumerate(((centre[c, 0] - gps[c, 0], sig["gps"]), (centre[c, 1] - gps[c, 1], sig["gps"]),
                                         (centre[c, 2] - alt[c], sig["alt"]))):
                J[b0 + 3 * c + a, 6 * c + a] = 1 / s
                res[b0 + 3 * c + a] = val / s
            d = rot0[c].T @ rot[c]
            ang = np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2
            for a in range(3):
                J[b0 + 3 * n + 3 * c + a, 6 * c + 3 + a] = 1 / sig["rot"]
                res[b0 + 3 * n + 3 * c + a] = ang[a] / sig["rot"]
        b1 = b0 + 6 * n
        nv = normal(pl)
        dist = pts @ nv - pl[2]
        pw = np.where(np.abs(dist) < 2 * sig["plane"], 1.0, np.sqrt(2 * sig["plane"] / np.maximum(np.abs(dist), 1e-12)))
        pw = pw / sig["plane"]
        pidx = np.arange(m)
        for c in range(3):
            J[b1 + pidx, 6 * n + 3 * pidx + c] = nv[c] * pw
        J[b1 + pidx, N - 3] = (pts @ ea) * pw
        J[b1 + pidx, N - 2] = (pts @ eb) * pw
        J[b1 + pidx, N - 1] = -pw
        res[b1:] = dist * pw
        A = J.T @ J
        A[np.diag_indices(N)] += lam * np.diag(A) + 1e-9
        dx = -np.linalg.solve(A, J.T @ res)
        centre = centre + dx[:6 * n].reshape(n, 6)[:, :3]
        rot = [rot[c] @ exp_so3(dx[6 * c + 3:6 * c + 6]) for c in range(n)]
        pts = pts + dx[6 * n:6 * n + 3 * m].reshape(m, 3)
        pl = pl + dx[N - 3:]
    r, y = residuals(rot, centre, pts)
    return rot, centre, pts, (normal(pl), pl[2]), np.linalg.norm(r, axis=1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("images_dir")
    ap.add_argument("dataset")
    ap.add_argument("--points", type=int, default=30000, help="seed points on the wall plane")
    ap.add_argument("--focal-px", type=float, default=589.0,
                    help="focal length at 640 px wide: the thermal core's 57 deg horizontal field of view")
    ap.add_argument("--k1", type=float, default=-0.28,
                    help="radial distortion (OpenCV k1): the eave's straightness in four top-row frames "
                         "gives -0.22 to -0.35")
    ap.add_argument("--px-per-m", type=float, default=215.0,
                    help="the wall's shift in pixels per metre of camera motion, for predicting where to "
                         "search (0: estimate it from neighbours in a row). On this set 215 registers the "
                         "most pairs (184, the estimate, 95 pairs; 200, 120; 215, 138)")
    ap.add_argument("--pair-m", type=float, default=3.2, help="register shots whose GPS positions are this close")
    ap.add_argument("--search-px", type=int, default=170, help="search radius around the GPS-predicted shift")
    ap.add_argument("--plane-sigma-m", type=float, default=0.05)
    ap.add_argument("--iters", type=int, default=20, help="bundle-adjustment iterations")
    a = ap.parse_args()

    if os.path.exists(a.dataset):
        sys.exit(f"{a.dataset} exists: give a new folder (nothing is overwritten)")
    paths = sorted(glob.glob(os.path.join(a.images_dir, "*.JPG")) + glob.glob(os.path.join(a.images_dir, "*.jpg")))
    if len(paths) < 3:
        sys.exit(f"{a.images_dir}: fewer than 3 JPEG images")
    meta = [read_xmp(p) for p in paths]
    lat0, lon0 = meta[0]["GpsLatitude"], meta[0]["GpsLongitude"]
    enu = np.array([[(m["GpsLongitude"] - lon0) * 111320 * math.cos(math.radians(lat0)),
                     (m["GpsLatitude"] - lat0) * 111320, m["RelativeAltitude"]] for m in meta])
    first = cv2.imread(paths[0])
    h, w = first.shape[:2]
    f = a.focal_px * w / 640.0
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    Kinv = np.linalg.inv(K)
    gimbal = [world_from_cam(m["GimbalYawDegree"], m["GimbalPitchDegree"], m["GimbalRollDegree"]) for m in meta]
    ref = world_from_cam(float(np.median([m["GimbalYawDegree"] for m in meta])), 0.0, 0.0)
    right, down, fwd = ref[:, 0], ref[:, 1], ref[:, 2]

    # Undistorted images (written out) and their copies turned into the reference orientation.
    mapx, mapy = cv2.initUndistortRectifyMap(K, np.array([a.k1, 0, 0, 0.0]), None, K, (w, h), cv2.CV_32FC1)
    clahe = cv2.createCLAHE(2.0, (8, 8))
    undist, turned, to_ref = [], [], []
    for p, R in zip(paths, gimbal):
        grey = cv2.cvtColor(cv2.imread(p), cv2.COLOR_BGR2GRAY)
        u = cv2.remap(grey, mapx, mapy, cv2.INTER_LINEAR)
        H = K @ ref.T @ R @ Kinv
        undist.append(u)
        to_ref.append(H)
        turned.append(clahe.apply(cv2.warpPerspective(u, H, (w, h))).astype(np.float32))
    g = np.stack([enu @ right, enu @ down], 1)
    n = len(paths)

    def predicted(i, j, scale):
        return -scale * (g[j] - g[i])

    # Scale (px per metre on the wall): given, or from neighbours in a row searched widely.
    first_pass = []
    for i in range(n - 1 if a.px_per_m <= 0 else 0):
        j = i + 1
        if abs(enu[j, 2] - enu[i, 2]) < 0.05 and 0.5 < np.linalg.norm(g[j] - g[i]) < 2.0:
            m = register_pair(turned[i], turned[j], predicted(i, j, 200.0), 2 * a.search_px)
            if m is not None:
                t = (m[:, 2:4] - m[:, 0:2]).mean(0)
                first_pass.append(abs(t[0]) / abs(g[j, 0] - g[i, 0]))
    if a.px_per_m > 0:
        scale = a.px_per_m
    elif len(first_pass) < 5:
        sys.exit(f"only {len(first_pass)} neighbouring shots registered: cannot estimate the wall's scale")
    else:
        scale = float(np.median(first_pass))
        print(f"scale from {len(first_pass)} neighbours in a row: {scale:.1f} px/m", flush=True)
    print(f"predicting shifts at {scale:.1f} px/m (a wall ~{f / scale:.2f} m away); registering pairs ...", flush=True)
    pairs = {}
    for i in range(n):
        for j in range(i + 1, n):
            if np.linalg.norm(enu[j] - enu[i]) <= a.pair_m:
                m = register_pair(turned[i], turned[j], predicted(i, j, scale), a.search_px)
                if m is not None:
                    pairs[(i, j)] = m
    offsets, active = solve_offsets(n, pairs, g, scale, 0.5)
    print(f"{len(pairs)} pairs registered, {len(active)} agree with the in-plane solve", flush=True)

    # Points: one per agreeing patch, observed in both shots (back in each camera's own pixels).
    def to_cam(i, xy):
        q = np.c_[xy, np.ones(len(xy))] @ np.linalg.inv(to_ref[i]).T
        return q[:, :2] / q[:, 2:]

    origin = enu.mean(0)
    depth = f / scale
    centre = np.array([origin + right * (offsets[i, 0] - offsets[:, 0].mean()) / scale
                       + down * (offsets[i, 1] - offsets[:, 1].mean()) / scale for i in range(n)])
    d0 = fwd @ origin + depth
    obs_cam, obs_pt, uv, pts = [], [], [], []
    for (i, j), m in active.items():
        if len(m) > 8:
            m = m[np.linspace(0, len(m) - 1, 8).astype(int)]
        ui, uj = to_cam(i, m[:, 0:2]), to_cam(j, m[:, 2:4])
        for k in range(len(m)):
            ray = gimbal[i] @ Kinv @ np.array([ui[k, 0], ui[k, 1], 1.0])
            pts.append(centre[i] + (d0 - fwd @ centre[i]) / (fwd @ ray) * ray)
            obs_cam += [i, j]
            obs_pt += [len(pts) - 1] * 2
            uv += [ui[k], uj[k]]
    obs_cam, obs_pt, uv, pts = np.array(obs_cam), np.array(obs_pt), np.array(uv), np.array(pts)
    seen = np.zeros(n, bool)
    seen[obs_cam] = True
    print(f"bundle adjustment: {n} cameras ({seen.sum()} in a registered pair), {len(pts)} points, "
          f"{len(uv)} observations ...", flush=True)
    sig = {"gps": 1.5, "alt": 0.15, "rot": math.radians(1.5), "plane": a.plane_sigma_m}
    rot, centre, pts, (nv, dist), err = bundle_adjust(
        K, gimbal, centre, obs_cam, obs_pt, uv, pts, {"fwd": fwd, "right": right, "down": down, "d": d0},
        enu[:, :2], enu[:, 2], sig, a.iters)
    tilt = math.degrees(math.acos(min(1.0, float(nv @ fwd))))
    moved = np.linalg.norm(centre[:, :2] - enu[:, :2], axis=1)[seen]
    turn = [math.degrees(math.acos(min(1.0, (np.trace(gimbal[c].T @ rot[c]) - 1) / 2))) for c in range(n)]
    print(f"reprojection error median {np.median(err):.2f} px, 90th percentile {np.percentile(err, 90):.2f} px; "
          f"wall {float(np.median(dist - centre[seen] @ nv)):.2f} m away, {tilt:.1f} deg off the mean heading; "
          f"cameras moved from GPS by {np.median(moved):.2f} m (median), turned from the gimbal angles by "
          f"{np.median(np.array(turn)[seen]):.2f} deg")

    os.makedirs(os.path.join(a.dataset, "images"), exist_ok=False)
    os.makedirs(os.path.join(a.dataset, "sparse", "0"))
    images, seeds, left_out = [], [], []
    for c, p in enumerate(paths):
        if not seen[c]:
            left_out.append(os.path.basename(p))
            continue
        stem = os.path.splitext(os.path.basename(p))[0] + ".png"
        cv2.imwrite(os.path.join(a.dataset, "images", stem), undist[c])
        cw = rot[c].T
        t = -cw @ centre[c]
        images.append((quat_from_R(cw), t, stem))
        us, vs = np.meshgrid(np.arange(4, w, 8), np.arange(4, h, 8))
        rays = rot[c] @ (Kinv @ np.stack([us.ravel(), vs.ravel(), np.ones(us.size)]))
        s = (dist - nv @ centre[c]) / (nv @ rays)
        ok = s > 0
        seeds.append(np.vstack([centre[c][:, None] + rays[:, ok] * s[ok], undist[c][vs.ravel()[ok], us.ravel()[ok]][None]]).T)
    seeds = np.concatenate(seeds)
    if len(seeds) > a.points:
        seeds = seeds[np.random.default_rng(0).choice(len(seeds), a.points, replace=False)]
    write_colmap_text(os.path.join(a.dataset, "sparse", "0"), w, h, K, images, seeds)
    report = {
        "views": len(images), "left_out": left_out, "pairs_registered": len(pairs), "pairs_used": len(active),
        "points": int(len(pts)), "observations": int(len(uv)), "scale_px_per_m": scale,
        "reprojection_px": {"median": float(np.median(err)), "p90": float(np.percentile(err, 90)),
                            "max": float(err.max())},
        "wall_distance_m": float(np.median(dist - centre[seen] @ nv)), "wall_tilt_deg": tilt,
        "moved_from_gps_m_median": float(np.median(moved)), "k1": a.k1, "focal_px": f,
    }
    with open(os.path.join(a.dataset, "poses.json"), "w") as fo:
        json.dump(report, fo, indent=2)
    print(f"{len(images)} of {n} views posed, {len(seeds)} seed points; written to {a.dataset}"
          + (f"; left out (no registered neighbour): {', '.join(left_out)}" if left_out else ""))


if __name__ == "__main__":
    main()
