//! The sparse truncated signed-distance volume: blocks of [`BLOCK`]³ voxels, allocated where
//! the views' surfaces are ([`Volume::touched_blocks`], [`Volume::allocate`]), updated by
//! projective fusion of depth, temperature and colour ([`Volume::integrate`]).
//!
//! Module docs of [`crate::mesh`] for the method; the layout here:
//!
//! - voxel `idx` (global integer coordinates) has its centre at `(idx + ½)·voxel_m` in the world
//!   frame; block `key` holds voxels `key·BLOCK + (0..BLOCK)³`;
//! - the blocks' data is one `Vec<f32>`, block after block; a block is `channels` planes of
//!   `BLOCK³` values (x fastest, then y, then z): signed distance (units of the truncation,
//!   `[−1, 1]`), its weight, the temperature (kelvin, running mean) and its weight, and with
//!   colour the red, green and blue means (`[0, 1]`) and their weight: 8 KiB a block without
//!   colour, 16 KiB with. Weights are sums of the observations' incidence weights
//!   ([`incidence_weights`]).

use std::collections::{HashMap, HashSet};

use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;

use super::error::MeshError;
use crate::camera::PinholeCamera;

/// Voxels along a block's edge.
pub const BLOCK: usize = 8;
/// Voxels of a block.
pub const BLOCK_VOXELS: usize = BLOCK * BLOCK * BLOCK;

/// Channel (plane) indices of a block's data.
pub(crate) mod ch {
    pub const TSDF: usize = 0;
    pub const WEIGHT: usize = 1;
    pub const KELVIN: usize = 2;
    pub const KELVIN_W: usize = 3;
    pub const RED: usize = 4;
    pub const RGB_W: usize = 7;
    /// Channels without / with colour.
    pub const PLAIN: usize = 4;
    pub const COLOUR: usize = 8;
}

/// Side of the square pixel tiles whose maximum depth culls hidden blocks.
const TILE: usize = 16;
/// Blocks whose projection covers more tiles than this skip the depth cull (they are near the
/// camera; reading the tiles would cost more than the voxels).
const MAX_CULL_TILES: usize = 64;

/// One rendered view: depth, temperature and optionally colour per pixel, row-major, top row
/// first, `camera.width × camera.height`.
#[derive(Debug, Clone, Copy)]
pub struct Frame<'a> {
    pub camera: &'a PinholeCamera,
    /// Camera-frame z of the surface, metres; NaN where there is no surface.
    pub depth_m: &'a [f32],
    /// Surface temperature, kelvin (NaN: none; only depth is fused there).
    pub kelvin: &'a [f32],
    /// Planar colour, the R, G and B planes one after the other (`3·w·h`), in `[0, 1]`.
    pub rgb: Option<&'a [f32]>,
}

impl Frame<'_> {
    /// Checks the buffers against the camera's pixel count. [`Volume::integrate`] reads a
    /// frame that fails this only where its buffers have values (it never panics), so check
    /// first.
    pub fn check(&self) -> Result<(), MeshError> {
        let (width, height) = (self.camera.width, self.camera.height);
        let n = width * height;
        let size = |buffer: &'static str, expected: usize, actual: usize| {
            if expected == actual {
                Ok(())
            } else {
                Err(MeshError::FrameSize {
                    width,
                    height,
                    buffer,
                    expected,
                    actual,
                })
            }
        };
        size("depth_m", n, self.depth_m.len())?;
        size("kelvin", n, self.kelvin.len())?;
        if let Some(rgb) = self.rgb {
            size("rgb", 3 * n, rgb.len())?;
        }
        Ok(())
    }
}

/// One voxel's fused values ([`Volume::voxel`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Voxel {
    /// Signed distance in units of the truncation, `[−1, 1]`, positive in front of surfaces.
    pub tsdf: f32,
    /// Observations of the distance, each weighted by its incidence ([`incidence_weights`]):
    /// head-on-equivalent observations.
    pub weight: f32,
    /// Mean temperature of the near-surface observations, kelvin.
    pub kelvin: f32,
    pub kelvin_weight: f32,
    /// Mean colour (`None`: a volume without colour).
    pub rgb: Option<[f32; 3]>,
    pub rgb_weight: f32,
}

/// The sparse TSDF volume.
#[derive(Debug, Clone)]
pub struct Volume {
    voxel_m: f64,
    trunc_m: f64,
    colour: bool,
    keys: Vec<[i32; 3]>,
    index: HashMap<[i32; 3], u32>,
    data: Vec<f32>,
}

/// Floor of `x` as an `i64` block or voxel coordinate, `None` beyond what `i32` block keys
/// address.
fn coord(x: f64) -> Option<i64> {
    const LIMIT: f64 = (1u64 << 33) as f64;
    let f = x.floor();
    (f.abs() < LIMIT).then_some(f as i64)
}

/// Block key of global voxel coordinates.
fn block_of(v: i64) -> i64 {
    v.div_euclid(BLOCK as i64)
}

impl Volume {
    /// An empty volume of `voxel_m` voxels with truncation `trunc_m` (both positive and
    /// finite: the caller checks them; others leave every update out), fusing colour when
    /// `colour`.
    pub fn new(voxel_m: f64, trunc_m: f64, colour: bool) -> Self {
        Self {
            voxel_m,
            trunc_m,
            colour,
            keys: Vec::new(),
            index: HashMap::new(),
            data: Vec::new(),
        }
    }

    fn channels(colour: bool) -> usize {
        if colour { ch::COLOUR } else { ch::PLAIN }
    }

    fn stride(&self) -> usize {
        Self::channels(self.colour) * BLOCK_VOXELS
    }

    fn valid_sizes(voxel_m: f64, trunc_m: f64) -> bool {
        voxel_m > 0.0 && voxel_m.is_finite() && trunc_m > 0.0 && trunc_m.is_finite()
    }

    /// Adds to `out` the key of every block holding a voxel centre that [`Volume::integrate`]
    /// could update with this frame within the truncation band (`|sdf| ≤ trunc_m`), for
    /// sizing the volume before allocating it.
    ///
    /// Each pixel with a depth `d` is back-projected: the segment of its ray from camera depth
    /// `d − trunc_m` to `d + trunc_m`, cut into pieces no longer than a block, marks the blocks
    /// of every voxel centre within the bounding box of a piece widened by the half pixel
    /// footprint at the piece's far end, `½·z·√(fx⁻² + fy⁻²)` (a voxel centre farther from the
    /// ray does not project to this pixel). The allocation is therefore conservative: no voxel
    /// the fusion can move within the band is left out (it would leave a hole). Consecutive
    /// pixels of a row mostly mark the same blocks and are merged before the set sees them;
    /// rows run on rayon's pool and nothing is allocated per pixel. The set does not depend on
    /// the thread count.
    pub fn touched_blocks(frame: &Frame, voxel_m: f64, trunc_m: f64, out: &mut HashSet<[i32; 3]>) {
        if !Self::valid_sizes(voxel_m, trunc_m) {
            return;
        }
        let cam = frame.camera;
        let (w, h) = (cam.width, cam.height);
        let n = (w * h).min(frame.depth_m.len());
        if w == 0 || n == 0 {
            return;
        }
        let world_from_cam = cam.cam_from_world.inverse();
        let rot = DMat3::from_quat(world_from_cam.rotation);
        let origin = world_from_cam.translation_m;
        let lateral = 0.5 * (cam.fx_px.powi(-2) + cam.fy_px.powi(-2)).sqrt();
        if !(lateral.is_finite() && origin.is_finite()) {
            return;
        }
        let block_m = voxel_m * BLOCK as f64;
        // Block range of the voxel centres (i + ½)·voxel within [lo, hi] per axis.
        let range = |lo: DVec3, hi: DVec3| -> Option<([i64; 3], [i64; 3])> {
            let mut r = ([0i64; 3], [0i64; 3]);
            for a in 0..3 {
                let l = coord(-(-lo[a] / voxel_m + 0.5).floor())?;
                let u = coord(hi[a] / voxel_m - 0.5)?;
                if l > u {
                    return None;
                }
                r.0[a] = block_of(l);
                r.1[a] = block_of(u);
            }
            Some(r)
        };
        let rows: Vec<Vec<([i64; 3], [i64; 3])>> = (0..n.div_ceil(w))
            .into_par_iter()
            .map(|row| {
                let mut marks: Vec<([i64; 3], [i64; 3])> = Vec::new();
                let start = row * w;
                for (col, &d) in frame.depth_m[start..(start + w).min(n)].iter().enumerate() {
                    if !(d > 0.0 && d.is_finite()) {
                        continue;
                    }
                    let d = f64::from(d);
                    let dir = rot
                        * DVec3::new(
                            (col as f64 - cam.cx_px) / cam.fx_px,
                            (row as f64 - cam.cy_px) / cam.fy_px,
                            1.0,
                        );
                    let z0 = (d - trunc_m).max(0.0);
                    let z1 = d + trunc_m;
                    let pieces =
                        ((z1 - z0) * dir.length() / block_m).ceil().clamp(1.0, 1e6) as usize;
                    for k in 0..pieces {
                        let za = z0 + (z1 - z0) * k as f64 / pieces as f64;
                        let zb = z0 + (z1 - z0) * (k + 1) as f64 / pieces as f64;
                        let (qa, qb) = (origin + dir * za, origin + dir * zb);
                        let r = DVec3::splat(lateral * zb);
                        if let Some(m) = range(qa.min(qb) - r, qa.max(qb) + r)
                            && marks.last() != Some(&m)
                        {
                            marks.push(m);
                        }
                    }
                }
                marks
            })
            .collect();
        for (lo, hi) in rows.into_iter().flatten() {
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        out.insert([x as i32, y as i32, z as i32]);
                    }
                }
            }
        }
    }

    /// Bytes one block costs: its data plus its key and index entry (an estimate of the hash
    /// table's share, including its slack).
    pub fn bytes_per_block(colour: bool) -> usize {
        Self::channels(colour) * BLOCK_VOXELS * std::mem::size_of::<f32>() + 48
    }

    /// Allocates the blocks `keys` not yet in the volume (unobserved: weight 0).
    pub fn allocate(&mut self, keys: impl IntoIterator<Item = [i32; 3]>) {
        let keys = keys.into_iter();
        let stride = self.stride();
        let extra = keys.size_hint().0;
        self.keys.reserve_exact(extra);
        self.index.reserve(extra);
        self.data.reserve_exact(extra * stride);
        for key in keys {
            if let std::collections::hash_map::Entry::Vacant(e) = self.index.entry(key) {
                e.insert(self.keys.len() as u32);
                self.keys.push(key);
                self.data.resize(self.data.len() + stride, 0.0);
            }
        }
    }

    /// Blocks allocated.
    pub fn blocks(&self) -> usize {
        self.keys.len()
    }

    pub fn voxel_m(&self) -> f64 {
        self.voxel_m
    }

    pub fn trunc_m(&self) -> f64 {
        self.trunc_m
    }

    /// Whether the volume fuses colour.
    pub fn colour(&self) -> bool {
        self.colour
    }

    /// Memory held by the volume, bytes (data, keys and index, by capacity).
    pub fn memory_bytes(&self) -> usize {
        self.data.capacity() * std::mem::size_of::<f32>()
            + self.keys.capacity() * std::mem::size_of::<[i32; 3]>()
            + self.index.capacity() * (std::mem::size_of::<([i32; 3], u32)>() + 1)
    }

    /// Block keys in allocation order.
    pub fn keys(&self) -> &[[i32; 3]] {
        &self.keys
    }

    /// Position of block `key` in [`Volume::keys`].
    pub fn block_index(&self, key: [i32; 3]) -> Option<usize> {
        self.index.get(&key).map(|&i| i as usize)
    }

    /// Data of block `i` (allocation order): `channels × BLOCK³` values.
    pub(crate) fn block_data(&self, i: usize) -> &[f32] {
        let s = self.stride();
        &self.data[i * s..(i + 1) * s]
    }

    /// The fused values of voxel `idx` (global voxel coordinates), `None` when its block is
    /// not allocated.
    pub fn voxel(&self, idx: [i64; 3]) -> Option<Voxel> {
        let key = idx.map(|v| block_of(v) as i32);
        let b = self.block_index(key)?;
        let l = idx.map(|v| v.rem_euclid(BLOCK as i64) as usize);
        let v = l[0] + BLOCK * (l[1] + BLOCK * l[2]);
        let d = self.block_data(b);
        let at = |c: usize| d[c * BLOCK_VOXELS + v];
        Some(Voxel {
            tsdf: at(ch::TSDF),
            weight: at(ch::WEIGHT),
            kelvin: at(ch::KELVIN),
            kelvin_weight: at(ch::KELVIN_W),
            rgb: self
                .colour
                .then(|| [at(ch::RED), at(ch::RED + 1), at(ch::RED + 2)]),
            rgb_weight: if self.colour { at(ch::RGB_W) } else { 0.0 },
        })
    }

    /// Fuses one frame into the allocated blocks (projective TSDF, each observation weighted
    /// by its [`incidence_weights`]; module docs of [`crate::mesh`]). Blocks run in parallel
    /// on rayon's pool, each voxel on its own, so the result is the same bits whatever the
    /// thread count. Buffers shorter than the camera's pixel count ([`Frame::check`]) read as
    /// "no surface" where they have no value; colour is fused only into a volume made with
    /// colour.
    pub fn integrate(&mut self, frame: &Frame) {
        if !Self::valid_sizes(self.voxel_m, self.trunc_m) || self.keys.is_empty() {
            return;
        }
        let cam = frame.camera;
        let (w, h) = (cam.width, cam.height);
        if w == 0 || h == 0 {
            return;
        }
        let n = w * h;
        let Some(tiles) = DepthTiles::new(frame.depth_m, w, h) else {
            return;
        };
        let rgb = frame.rgb.filter(|c| self.colour && c.len() >= 3 * n);
        let rot = DMat3::from_quat(cam.cam_from_world.rotation);
        let t = cam.cam_from_world.translation_m;
        let planes = frustum_planes(cam);
        let voxel = self.voxel_m;
        let trunc = self.trunc_m as f32;
        let radius = 0.5 * (BLOCK as f64 - 1.0) * voxel * 3f64.sqrt();
        let (fx, fy, cx, cy) = (
            cam.fx_px as f32,
            cam.fy_px as f32,
            cam.cx_px as f32,
            cam.cy_px as f32,
        );
        let (wf, hf) = (w as f32, h as f32);
        let step = [
            (rot * DVec3::new(voxel, 0.0, 0.0)).as_vec3(),
            (rot * DVec3::new(0.0, voxel, 0.0)).as_vec3(),
            (rot * DVec3::new(0.0, 0.0, voxel)).as_vec3(),
        ];
        let incidence = incidence_weights(frame, self.trunc_m);
        let stride = self.stride();
        let colour = self.colour;
        self.data
            .par_chunks_mut(stride)
            .zip(self.keys.par_iter())
            .for_each(|(blk, key)| {
                let k = DVec3::new(key[0] as f64, key[1] as f64, key[2] as f64) * BLOCK as f64;
                let centre = rot * ((k + DVec3::splat(0.5 * BLOCK as f64)) * voxel) + t;
                if planes.iter().any(|p| p.dot(centre) < -radius) {
                    return;
                }
                if !tiles.may_update(cam, centre, radius, f64::from(trunc)) {
                    return;
                }
                let c0 = (rot * ((k + DVec3::splat(0.5)) * voxel) + t).as_vec3();
                let (tsdf, rest) = blk.split_at_mut(BLOCK_VOXELS);
                let (weight, rest) = rest.split_at_mut(BLOCK_VOXELS);
                let (kelvin, rest) = rest.split_at_mut(BLOCK_VOXELS);
                let (kelvin_w, rest) = rest.split_at_mut(BLOCK_VOXELS);
                let mut vi = 0usize;
                for z in 0..BLOCK {
                    for y in 0..BLOCK {
                        let row = c0 + step[1] * y as f32 + step[2] * z as f32;
                        for x in 0..BLOCK {
                            let v = vi;
                            vi += 1;
                            let p: Vec3 = row + step[0] * x as f32;
                            if p.z <= 0.0 || p.z.is_nan() {
                                continue;
                            }
                            let col = (fx * p.x / p.z + cx + 0.5).floor();
                            let rw = (fy * p.y / p.z + cy + 0.5).floor();
                            if !(col >= 0.0 && col < wf && rw >= 0.0 && rw < hf) {
                                continue;
                            }
                            let pix = rw as usize * w + col as usize;
                            // 0: no depth at the pixel
                            let om = incidence[pix];
                            if om == 0.0 {
                                continue;
                            }
                            let sdf = frame.depth_m[pix] - p.z;
                            if sdf < -trunc {
                                continue;
                            }
                            let obs = (sdf / trunc).min(1.0);
                            let wt = weight[v];
                            tsdf[v] = (tsdf[v] * wt + om * obs) / (wt + om);
                            weight[v] = wt + om;
                            if sdf.abs() >= trunc {
                                continue;
                            }
                            if let Some(&kv) = frame.kelvin.get(pix)
                                && kv.is_finite()
                            {
                                let kw = kelvin_w[v];
                                kelvin[v] = (kelvin[v] * kw + om * kv) / (kw + om);
                                kelvin_w[v] = kw + om;
                            }
                            if colour && let Some(rgb) = rgb {
                                let c = [rgb[pix], rgb[n + pix], rgb[2 * n + pix]];
                                if c.iter().all(|x| x.is_finite()) {
                                    let cw = rest[3 * BLOCK_VOXELS + v];
                                    for (j, cj) in c.into_iter().enumerate() {
                                        let s = &mut rest[j * BLOCK_VOXELS + v];
                                        *s = (*s * cw + om * cj) / (cw + om);
                                    }
                                    rest[3 * BLOCK_VOXELS + v] = cw + om;
                                }
                            }
                        }
                    }
                }
            });
    }
}

/// Lowest weight of an observation (grazing incidence, or a pixel without neighbours).
pub const MIN_INCIDENCE_WEIGHT: f32 = 0.05;

/// Weight of each pixel's observation: `|cos θ|`, θ the angle between the pixel's ray and the
/// normal of the surface it sees, at least [`MIN_INCIDENCE_WEIGHT`]; 0 where the pixel has no
/// depth (or the buffer none). The normal is the cross product of the back-projected
/// neighbours' differences (central where both neighbours along an axis have a depth within
/// `3·trunc_m` of the pixel's, one-sided where one has; the minimum weight where none has).
/// Rows on rayon's pool, each pixel on its own.
pub fn incidence_weights(frame: &Frame, trunc_m: f64) -> Vec<f32> {
    let cam = frame.camera;
    let (w, h) = (cam.width, cam.height);
    let n = w * h;
    let (fx, fy, cx, cy) = (cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px);
    let near = 3.0 * trunc_m;
    let point = |c: usize, r: usize| -> Option<DVec3> {
        let d = f64::from(*frame.depth_m.get(r * w + c)?);
        (d > 0.0 && d.is_finite())
            .then(|| DVec3::new((c as f64 - cx) / fx * d, (r as f64 - cy) / fy * d, d))
    };
    let mut out = vec![0.0f32; n];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(r, row)| {
            for (c, o) in row.iter_mut().enumerate() {
                let Some(p) = point(c, r) else {
                    continue;
                };
                let nb = |q: Option<DVec3>| q.filter(|q| (q.z - p.z).abs() < near);
                let diff = |a: Option<DVec3>, b: Option<DVec3>| match (nb(a), nb(b)) {
                    (Some(a), Some(b)) => Some(b - a),
                    (Some(a), None) => Some(p - a),
                    (None, Some(b)) => Some(b - p),
                    (None, None) => None,
                };
                let du = diff(
                    c.checked_sub(1).and_then(|c| point(c, r)),
                    (c + 1 < w).then(|| point(c + 1, r)).flatten(),
                );
                let dv = diff(
                    r.checked_sub(1).and_then(|r| point(c, r)),
                    (r + 1 < h).then(|| point(c, r + 1)).flatten(),
                );
                let cos = match (du, dv) {
                    (Some(du), Some(dv)) => du
                        .cross(dv)
                        .try_normalize()
                        .map_or(0.0, |nrm| nrm.dot(p.normalize()).abs()),
                    _ => 0.0,
                };
                let cos = cos as f32;
                *o = if cos.is_finite() {
                    cos.max(MIN_INCIDENCE_WEIGHT)
                } else {
                    MIN_INCIDENCE_WEIGHT
                };
            }
        });
    out
}

/// The inward unit normals of the four side planes of the camera's frustum (the pixel area
/// `u ∈ [−½, w − ½]`, `v ∈ [−½, h − ½]`) and of the image plane `z = 0`, in the camera frame:
/// a point is inside when every `n·p ≥ 0`.
fn frustum_planes(cam: &PinholeCamera) -> [DVec3; 5] {
    let (w, h) = (cam.width as f64, cam.height as f64);
    let n = |x: f64, y: f64, z: f64| {
        let v = DVec3::new(x, y, z);
        v.try_normalize().unwrap_or(DVec3::ZERO)
    };
    [
        n(cam.fx_px, 0.0, cam.cx_px + 0.5),
        n(-cam.fx_px, 0.0, w - 0.5 - cam.cx_px),
        n(0.0, cam.fy_px, cam.cy_px + 0.5),
        n(0.0, -cam.fy_px, h - 0.5 - cam.cy_px),
        DVec3::Z,
    ]
}

/// The largest finite depth of each `TILE × TILE` pixel tile (−∞: none), to skip blocks that
/// lie wholly behind the surfaces (`sdf < −trunc` everywhere) or see no surface at all.
struct DepthTiles {
    max_m: Vec<f64>,
    tiles_x: usize,
    tiles_y: usize,
    w: usize,
    h: usize,
}

impl DepthTiles {
    /// `None` when no pixel has a depth.
    fn new(depth_m: &[f32], w: usize, h: usize) -> Option<Self> {
        let (tiles_x, tiles_y) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut max_m = vec![f64::NEG_INFINITY; tiles_x * tiles_y];
        let mut any = false;
        for (p, &d) in depth_m.iter().enumerate().take(w * h) {
            if d > 0.0 && d.is_finite() {
                let t = (p / w / TILE) * tiles_x + (p % w) / TILE;
                max_m[t] = max_m[t].max(f64::from(d));
                any = true;
            }
        }
        any.then_some(Self {
            max_m,
            tiles_x,
            tiles_y,
            w,
            h,
        })
    }

    /// Whether a sphere at camera-frame `centre` of `radius` may hold a voxel this frame
    /// updates: false only when it lies in front of the image plane and every pixel its
    /// projection can cover has no depth or a depth more than `trunc` in front of it.
    fn may_update(&self, cam: &PinholeCamera, centre: DVec3, radius: f64, trunc: f64) -> bool {
        let near = centre.z - radius;
        if near <= 0.0 || near.is_nan() {
            return true;
        }
        // |Δu| ≤ fx·R·(z + |x|) / (z·(z − R)) for every point of the sphere
        let ru = cam.fx_px * radius * (centre.z + centre.x.abs()) / (centre.z * near);
        let rv = cam.fy_px * radius * (centre.z + centre.y.abs()) / (centre.z * near);
        let u = cam.fx_px * centre.x / centre.z + cam.cx_px;
        let v = cam.fy_px * centre.y / centre.z + cam.cy_px;
        let col = |x: f64, n: usize| (x + 0.5).floor().clamp(0.0, n as f64 - 1.0) as usize;
        let (c0, c1) = (col(u - ru, self.w) / TILE, col(u + ru, self.w) / TILE);
        let (r0, r1) = (col(v - rv, self.h) / TILE, col(v + rv, self.h) / TILE);
        if (c1 - c0 + 1) * (r1 - r0 + 1) > MAX_CULL_TILES {
            return true;
        }
        let mut deepest = f64::NEG_INFINITY;
        for r in r0..=r1.min(self.tiles_y - 1) {
            for c in c0..=c1.min(self.tiles_x - 1) {
                deepest = deepest.max(self.max_m[r * self.tiles_x + c]);
            }
        }
        deepest + trunc >= near
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    fn camera() -> PinholeCamera {
        PinholeCamera::look_at([0.0, 0.0, -2.0], [0.0; 3], [0.0, -1.0, 0.0], 40.0, 32, 24)
    }

    #[test]
    fn a_flat_view_fuses_the_projective_distance() {
        let cam = camera();
        let n = cam.width * cam.height;
        // a wall at world z = 0 (camera depth 2 m), 300 K
        let depth = vec![2.0f32; n];
        let kelvin = vec![300.0f32; n];
        let frame = Frame {
            camera: &cam,
            depth_m: &depth,
            kelvin: &kelvin,
            rgb: None,
        };
        frame.check().unwrap();
        let (voxel, trunc) = (0.01, 0.03);
        let mut keys = HashSet::new();
        Volume::touched_blocks(&frame, voxel, trunc, &mut keys);
        assert!(
            keys.contains(&[0, 0, 0]) && keys.contains(&[0, 0, -1]),
            "{keys:?}"
        );
        for k in &keys {
            assert!(
                (-2..=1).contains(&k[2]),
                "block {k:?} far from the wall z = 0"
            );
        }
        let mut vol = Volume::new(voxel, trunc, false);
        vol.allocate(keys.iter().copied());
        assert_eq!(vol.blocks(), keys.len());
        vol.integrate(&frame);
        // voxel centre z = (i + ½)·1 cm; camera depth = 2 + z; sdf = −z
        for iz in [-4i64, -2, -1, 0, 2] {
            let v = vol.voxel([0, 0, iz]).unwrap();
            let want = (-(iz as f32 + 0.5) / 3.0).min(1.0);
            assert!(
                (v.tsdf - want).abs() < 1e-4,
                "voxel z {iz}: tsdf {} expected {want}",
                v.tsdf
            );
            assert!(
                (v.weight - 1.0).abs() < 1e-3,
                "voxel z {iz}: one head-on observation, weight {}",
                v.weight
            );
        }
        let v = vol.voxel([0, 0, 0]).unwrap();
        assert!(
            (v.kelvin - 300.0).abs() < 1e-3 && v.kelvin_weight == v.weight,
            "{v:?}"
        );
        // beyond the truncation behind the wall: occluded, untouched
        assert_eq!(vol.voxel([0, 0, 3]).unwrap().weight, 0.0, "occluded voxel");
        // in front beyond the band: free space (+1), no temperature
        let free = vol.voxel([0, 0, -5]).unwrap();
        assert_eq!((free.tsdf, free.kelvin_weight), (1.0, 0.0), "{free:?}");
    }

    #[test]
    fn malformed_frames_are_reported_and_never_panic() {
        let cam = camera();
        let short = vec![2.0f32; 10];
        let frame = Frame {
            camera: &cam,
            depth_m: &short,
            kelvin: &short,
            rgb: None,
        };
        match frame.check() {
            Err(MeshError::FrameSize {
                buffer,
                expected,
                actual,
                ..
            }) => assert_eq!((buffer, expected, actual), ("depth_m", 768, 10)),
            other => panic!("expected FrameSize for depth_m, got {other:?}"),
        }
        let mut keys = HashSet::new();
        Volume::touched_blocks(&frame, 0.01, 0.03, &mut keys);
        let mut vol = Volume::new(0.01, 0.03, true);
        vol.allocate(keys);
        vol.integrate(&frame);
        // nonsense sizes leave everything out
        let mut none = HashSet::new();
        Volume::touched_blocks(&frame, 0.0, 0.03, &mut none);
        Volume::touched_blocks(&frame, f64::NAN, 0.03, &mut none);
        assert!(none.is_empty());
    }

    #[test]
    fn memory_is_counted() {
        let mut vol = Volume::new(0.01, 0.03, true);
        vol.allocate((0..10).map(|i| [i, 0, 0]));
        vol.allocate([[0, 0, 0], [0, 0, 1]]);
        assert_eq!(vol.blocks(), 11, "the repeated key is allocated once");
        assert!(
            vol.memory_bytes() >= 11 * 8 * 2048,
            "{}",
            vol.memory_bytes()
        );
        assert_eq!(Volume::bytes_per_block(false), 4 * 2048 + 48);
    }
}
