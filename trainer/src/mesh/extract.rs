//! Surface nets over the sparse TSDF: one vertex per cell the surface crosses, one quad per
//! voxel edge it crosses, welded across blocks (module docs of [`crate::mesh`] for the method
//! and why it is written here rather than taken from the `fast-surface-nets` crate).
//!
//! A cell is the cube between 8 voxel centres; it is named by its min corner, voxel `v`.
//! Extraction runs in two passes over the blocks in key order (each on rayon's pool, results
//! combined in that order, so the mesh is the same bits whatever the thread count):
//!
//! 1. the vertices: for each cell whose min corner lies in the block;
//! 2. the quads: for each voxel edge `(v, v + axis)` whose first voxel lies in the block, the
//!    vertices of its 4 cells are looked up in the blocks around (a binary search in the
//!    block's sorted cell list).

use std::collections::HashMap;

use rayon::prelude::*;

use super::tsdf::{BLOCK, BLOCK_VOXELS, Volume, ch};

/// A triangle mesh with a temperature per vertex.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// World metres.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals pointing out of the surface (toward free space); empty for point clouds
    /// read without normals.
    pub normals: Vec<[f32; 3]>,
    /// Temperature per vertex, kelvin (NaN: no temperature was observed near the vertex).
    pub kelvin: Vec<f32>,
    /// Colour per vertex.
    pub rgb: Option<Vec<[u8; 3]>>,
    /// Vertex indices, counter-clockwise seen from outside (right-hand normal outward).
    pub triangles: Vec<[u32; 3]>,
}

/// One vertex of the first pass, in its block's cell order.
#[derive(Debug, Clone, Copy)]
struct CellVertex {
    /// Local index of the cell's min corner in its block.
    local: u16,
    position: [f32; 3],
    normal: [f32; 3],
    kelvin: f32,
    rgb: [u8; 3],
}

/// Largest jump of the signed distance (units of the truncation) across a voxel edge that
/// still counts as a surface crossing: `max(1, 3·voxel/trunc)`. Module docs of
/// [`crate::mesh`] for why.
pub fn max_crossing_jump(volume: &Volume) -> f32 {
    (3.0 * volume.voxel_m() / volume.trunc_m()).max(1.0) as f32
}

/// The data of the 27 blocks around a block (offsets −1..=1 per axis), for reading voxels by
/// coordinates local to the centre block (`−8..16`).
struct Neighbourhood<'a> {
    data: [Option<&'a [f32]>; 27],
    /// Sorted positions of the blocks (for the vertex tables).
    sorted: [Option<usize>; 27],
}

impl<'a> Neighbourhood<'a> {
    fn new(volume: &'a Volume, key: [i32; 3], sorted_of: &HashMap<[i32; 3], usize>) -> Self {
        let mut data = [None; 27];
        let mut sorted = [None; 27];
        for (i, (d, s)) in data.iter_mut().zip(sorted.iter_mut()).enumerate() {
            let off = [
                (i % 3) as i32 - 1,
                ((i / 3) % 3) as i32 - 1,
                (i / 9) as i32 - 1,
            ];
            let k = [key[0] + off[0], key[1] + off[1], key[2] + off[2]];
            if let Some(b) = volume.block_index(k) {
                *d = Some(volume.block_data(b));
                *s = sorted_of.get(&k).copied();
            }
        }
        Self { data, sorted }
    }

    /// Neighbour slot and local voxel index of local coordinates `p` (each in `−8..16`).
    fn locate(p: [i32; 3]) -> (usize, usize) {
        let b = BLOCK as i32;
        let slot =
            (p[0].div_euclid(b) + 1) + 3 * (p[1].div_euclid(b) + 1) + 9 * (p[2].div_euclid(b) + 1);
        let l = p.map(|c| c.rem_euclid(b) as usize);
        (slot as usize, l[0] + BLOCK * (l[1] + BLOCK * l[2]))
    }

    /// `(tsdf, weight, data, local index)` of the voxel at local coordinates `p`.
    fn voxel(&self, p: [i32; 3]) -> Option<(f32, f32, &'a [f32], usize)> {
        let (slot, v) = Self::locate(p);
        let d = self.data[slot]?;
        Some((
            d[ch::TSDF * BLOCK_VOXELS + v],
            d[ch::WEIGHT * BLOCK_VOXELS + v],
            d,
            v,
        ))
    }
}

fn local_coords(v: usize) -> [i32; 3] {
    [
        (v % BLOCK) as i32,
        ((v / BLOCK) % BLOCK) as i32,
        (v / (BLOCK * BLOCK)) as i32,
    ]
}

/// Whether the edge between two voxels is a surface crossing: both observed enough, the sign
/// changes (negative = behind a surface), and the jump is a distance field's, not an occlusion
/// boundary's.
fn crossing(ta: f32, wa: f32, tb: f32, wb: f32, min_w: f32, max_jump: f32) -> bool {
    wa >= min_w && wb >= min_w && ((ta < 0.0) != (tb < 0.0)) && (ta - tb).abs() <= max_jump
}

/// Trilinear basis weight of corner `c` (bit 0 = x, 1 = y, 2 = z) at cell offset `f`.
fn basis(c: usize, f: [f32; 3]) -> f32 {
    (0..3)
        .map(|a| if c >> a & 1 == 1 { f[a] } else { 1.0 - f[a] })
        .product()
}

/// Interpolates channel planes `first..first + len` over the corners whose `weight_ch` is > 0,
/// with trilinear weights renormalised over them (their plain mean when those weights are all
/// zero); `None` when no corner has a value.
fn interpolate<const N: usize>(
    corners: &[(&[f32], usize); 8],
    f: [f32; 3],
    first: usize,
    weight_ch: usize,
) -> Option<[f32; N]> {
    let mut acc = [0.0f32; N];
    let mut total = 0.0f32;
    let mut plain = [0.0f32; N];
    let mut count = 0usize;
    for (c, &(d, v)) in corners.iter().enumerate() {
        if d[weight_ch * BLOCK_VOXELS + v] <= 0.0 {
            continue;
        }
        let w = basis(c, f);
        for (j, (a, p)) in acc.iter_mut().zip(plain.iter_mut()).enumerate() {
            let x = d[(first + j) * BLOCK_VOXELS + v];
            *a += w * x;
            *p += x;
        }
        total += w;
        count += 1;
    }
    if count == 0 {
        None
    } else if total > 0.0 {
        Some(acc.map(|a| a / total))
    } else {
        Some(plain.map(|p| p / count as f32))
    }
}

/// Pass 1: the vertices of the cells whose min corner is in the centre block.
fn block_vertices(
    nb: &Neighbourhood,
    key: [i32; 3],
    voxel_m: f64,
    colour: bool,
    min_w: f32,
    max_jump: f32,
) -> Vec<CellVertex> {
    let mut out = Vec::new();
    let origin = key.map(|k| i64::from(k) * BLOCK as i64);
    'cells: for cell in 0..BLOCK_VOXELS {
        let m = local_coords(cell);
        let mut t = [0.0f32; 8];
        let mut wgt = [0.0f32; 8];
        let mut corners: [(&[f32], usize); 8] = [(&[], 0); 8];
        let mut neg = 0;
        for c in 0..8 {
            let p = [
                m[0] + (c & 1) as i32,
                m[1] + (c >> 1 & 1) as i32,
                m[2] + (c >> 2 & 1) as i32,
            ];
            let Some((tc, wc, d, v)) = nb.voxel(p) else {
                continue 'cells;
            };
            if wc < min_w || wc.is_nan() {
                continue 'cells;
            }
            t[c] = tc;
            wgt[c] = wc;
            corners[c] = (d, v);
            neg += usize::from(tc < 0.0);
        }
        if neg == 0 || neg == 8 {
            continue;
        }
        // mean of the accepted edges' zero crossings, in cell coordinates
        let mut sum = [0.0f32; 3];
        let mut edges = 0;
        for a in 0..3 {
            for c in (0..8).filter(|c| c >> a & 1 == 0) {
                let e = c | 1 << a;
                if !crossing(t[c], wgt[c], t[e], wgt[e], min_w, max_jump) {
                    continue;
                }
                let s = t[c] / (t[c] - t[e]);
                for (b, x) in sum.iter_mut().enumerate() {
                    *x += if b == a { s } else { (c >> b & 1) as f32 };
                }
                edges += 1;
            }
        }
        if edges == 0 {
            continue;
        }
        let f = sum.map(|s| s / edges as f32);
        // gradient of the trilinear interpolant: points to positive distance (outward)
        let mut g = [0.0f32; 3];
        for (a, ga) in g.iter_mut().enumerate() {
            for c in (0..8).filter(|c| c >> a & 1 == 0) {
                let e = c | 1 << a;
                let w: f32 = (0..3)
                    .filter(|&b| b != a)
                    .map(|b| if c >> b & 1 == 1 { f[b] } else { 1.0 - f[b] })
                    .product();
                *ga += w * (t[e] - t[c]);
            }
        }
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let normal = if len > 0.0 && len.is_finite() {
            g.map(|x| x / len)
        } else {
            [0.0; 3]
        };
        let kelvin =
            interpolate::<1>(&corners, f, ch::KELVIN, ch::KELVIN_W).map_or(f32::NAN, |k| k[0]);
        let rgb = if colour {
            interpolate::<3>(&corners, f, ch::RED, ch::RGB_W).map_or([128; 3], |c| {
                c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
            })
        } else {
            [0; 3]
        };
        let position = [0, 1, 2]
            .map(|a| ((origin[a] + i64::from(m[a])) as f64 + 0.5 + f64::from(f[a])) * voxel_m);
        out.push(CellVertex {
            local: cell as u16,
            position: position.map(|x| x as f32),
            normal,
            kelvin,
            rgb,
        });
    }
    out
}

/// Pass 2: the triangles of the crossing edges whose first voxel is in the centre block.
fn block_triangles(
    nb: &Neighbourhood,
    cells: &[Vec<CellVertex>],
    base: &[u32],
    positions: impl Fn(u32) -> [f32; 3],
    min_w: f32,
    max_jump: f32,
) -> Vec<[u32; 3]> {
    let mut out = Vec::new();
    let vertex_of = |p: [i32; 3]| -> Option<u32> {
        let (slot, v) = Neighbourhood::locate(p);
        let s = nb.sorted[slot]?;
        let list = &cells[s];
        let i = list.binary_search_by_key(&(v as u16), |c| c.local).ok()?;
        Some(base[s] + i as u32)
    };
    for v in 0..BLOCK_VOXELS {
        let p = local_coords(v);
        let Some((ta, wa, _, _)) = nb.voxel(p) else {
            continue;
        };
        if wa < min_w || wa.is_nan() {
            continue;
        }
        for a in 0..3 {
            let mut q = p;
            q[a] += 1;
            let Some((tb, wb, _, _)) = nb.voxel(q) else {
                continue;
            };
            if !crossing(ta, wa, tb, wb, min_w, max_jump) {
                continue;
            }
            let (b, c) = ((a + 1) % 3, (a + 2) % 3);
            let cell = |db: i32, dc: i32| {
                let mut m = p;
                m[b] += db;
                m[c] += dc;
                vertex_of(m)
            };
            // counter-clockwise about +axis (b × c = axis)
            let (Some(q0), Some(q1), Some(q2), Some(q3)) =
                (cell(-1, -1), cell(0, -1), cell(0, 0), cell(-1, 0))
            else {
                continue;
            };
            // the normal points to positive distance: +axis when the first voxel is behind
            let quad = if ta < 0.0 {
                [q0, q1, q2, q3]
            } else {
                [q0, q3, q2, q1]
            };
            let d2 = |i: u32, j: u32| {
                let (x, y) = (positions(i), positions(j));
                (0..3).map(|k| (x[k] - y[k]) * (x[k] - y[k])).sum::<f32>()
            };
            // split along the shorter diagonal
            if d2(quad[0], quad[2]) <= d2(quad[1], quad[3]) {
                out.push([quad[0], quad[1], quad[2]]);
                out.push([quad[0], quad[2], quad[3]]);
            } else {
                out.push([quad[1], quad[2], quad[3]]);
                out.push([quad[1], quad[3], quad[0]]);
            }
        }
    }
    out
}

/// Extracts the zero level set of `volume` as a closed-where-observed triangle mesh. Voxels
/// whose weight (head-on-equivalent observations, [`super::tsdf::incidence_weights`]) is
/// below `min_weight` take no part, nor do never-observed ones whatever `min_weight`.
/// Vertices carry the fused temperature (and colour when the volume has it); vertices no
/// triangle uses are dropped. The same bits whatever the thread count.
pub fn extract(volume: &Volume, min_weight: f32) -> Mesh {
    let min_w = if min_weight > 0.0 {
        min_weight
    } else {
        f32::MIN_POSITIVE
    };
    let max_jump = max_crossing_jump(volume);
    let mut order: Vec<[i32; 3]> = volume.keys().to_vec();
    order.sort_unstable();
    let sorted_of: HashMap<[i32; 3], usize> =
        order.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let colour = volume.colour();
    let voxel_m = volume.voxel_m();

    let cells: Vec<Vec<CellVertex>> = order
        .par_iter()
        .map(|&key| {
            let nb = Neighbourhood::new(volume, key, &sorted_of);
            block_vertices(&nb, key, voxel_m, colour, min_w, max_jump)
        })
        .collect();
    let mut base = Vec::with_capacity(cells.len());
    let mut total = 0u32;
    for c in &cells {
        base.push(total);
        total += c.len() as u32;
    }
    let mut flat: Vec<CellVertex> = Vec::with_capacity(total as usize);
    for c in &cells {
        flat.extend_from_slice(c);
    }
    let positions = |i: u32| flat[i as usize].position;
    let triangles: Vec<Vec<[u32; 3]>> = order
        .par_iter()
        .map(|&key| {
            let nb = Neighbourhood::new(volume, key, &sorted_of);
            block_triangles(&nb, &cells, &base, positions, min_w, max_jump)
        })
        .collect();
    drop(cells);

    // drop unreferenced vertices, keeping the order
    let mut remap = vec![u32::MAX; flat.len()];
    for t in triangles.iter().flatten() {
        for &i in t {
            remap[i as usize] = 0;
        }
    }
    let mut mesh = Mesh {
        rgb: colour.then(Vec::new),
        ..Mesh::default()
    };
    for (i, v) in flat.iter().enumerate() {
        if remap[i] == u32::MAX {
            continue;
        }
        remap[i] = mesh.positions.len() as u32;
        mesh.positions.push(v.position);
        mesh.normals.push(v.normal);
        mesh.kelvin.push(v.kelvin);
        if let Some(rgb) = mesh.rgb.as_mut() {
            rgb.push(v.rgb);
        }
    }
    mesh.triangles = triangles
        .into_iter()
        .flatten()
        .map(|t| t.map(|i| remap[i as usize]))
        .collect();
    face_normals(&mut mesh);
    mesh
}

/// Replaces each vertex normal by the area-weighted mean of its triangles' normals (the
/// distance gradient stays where that mean vanishes). Triangles are summed in order.
fn face_normals(mesh: &mut Mesh) {
    let p = |i: u32| {
        let q = mesh.positions[i as usize];
        [f64::from(q[0]), f64::from(q[1]), f64::from(q[2])]
    };
    let mut acc = vec![[0.0f64; 3]; mesh.positions.len()];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(p);
        let (u, v) = (
            [0, 1, 2].map(|k| b[k] - a[k]),
            [0, 1, 2].map(|k| c[k] - a[k]),
        );
        // |u × v| is twice the area: the sum weights by area
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        for &i in t {
            for k in 0..3 {
                acc[i as usize][k] += n[k];
            }
        }
    }
    for (nrm, a) in mesh.normals.iter_mut().zip(acc) {
        let len = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        if len > 0.0 && len.is_finite() {
            *nrm = a.map(|x| (x / len) as f32);
        }
    }
}
