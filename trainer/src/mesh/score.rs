//! A mesh's vertices against a truth point cloud (the simulator's `truth/surface.ply`):
//! accuracy, completeness, Chamfer distance, precision/recall/F-score at a threshold, and the
//! temperature error where the geometry is right.
//!
//! Distances are **exact** Euclidean nearest-neighbour distances between point sets (mesh
//! vertices and truth points, not surfaces), found with a small static k-d tree (median
//! splits on the widest axis, exact pruning); queries run on rayon's pool and are summed in
//! input order, so the score does not depend on the thread count.
//!
//! **Crop**: with an evaluation volume (the truth's `region_m` header comment,
//! [`super::plyio::read_region`]), only mesh vertices inside it are scored
//! (`vertices_cropped` counts the others): the truth covers the region of the scene meant to
//! be scored (the simulator's: inside the camera orbit, and the free space in front of a
//! wall), and a correct surface beyond it — the far ground — must not count as an error, while
//! a floater inside it does. The usual practice of mesh benchmarks (a scene's evaluation
//! volume).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::extract::Mesh;
use super::plyio::Region;

/// The score of a mesh against a truth surface (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MeshScore {
    /// The threshold of precision, recall and the temperature error, metres.
    pub tau_m: f64,
    /// Mean distance from a mesh vertex to its nearest truth point (NaN: no vertex or no
    /// truth point).
    pub accuracy_m: f64,
    /// Mean distance from a truth point to its nearest mesh vertex (NaN: as above).
    pub completeness_m: f64,
    /// `(accuracy + completeness) / 2`.
    pub chamfer_m: f64,
    /// Fraction of mesh vertices closer than `tau_m` to the truth.
    pub precision: f64,
    /// Fraction of truth points closer than `tau_m` to the mesh.
    pub recall: f64,
    /// `2PR / (P + R)` (0 when both are 0).
    pub f_score: f64,
    /// Mean `|kelvin − kelvin of the nearest truth point|` over the mesh vertices closer than
    /// `tau_m` to the truth whose temperatures are both finite (NaN: no such vertex).
    pub kelvin_mae: f64,
    /// Mesh vertices scored (inside the crop).
    pub vertices: usize,
    /// Mesh vertices outside the evaluation volume, not scored.
    #[serde(default)]
    pub vertices_cropped: usize,
    pub truth_points: usize,
}

/// A static k-d tree over points (stored reordered, with their original indices).
#[derive(Debug)]
struct KdTree {
    points: Vec<[f64; 3]>,
    index: Vec<u32>,
    /// Split axis of the node at each position (the median of its range).
    axis: Vec<u8>,
}

/// Ranges this small are searched linearly.
const LEAF: usize = 8;

impl KdTree {
    fn new(points: &[[f32; 3]]) -> Self {
        let mut items: Vec<([f64; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (p.map(f64::from), i as u32))
            .collect();
        let mut axis = vec![0u8; items.len()];
        Self::build(&mut items, &mut axis);
        Self {
            points: items.iter().map(|x| x.0).collect(),
            index: items.iter().map(|x| x.1).collect(),
            axis,
        }
    }

    fn build(items: &mut [([f64; 3], u32)], axis: &mut [u8]) {
        if items.len() <= LEAF {
            return;
        }
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (p, _) in items.iter() {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let a = (0..3)
            .max_by(|&x, &y| (hi[x] - lo[x]).total_cmp(&(hi[y] - lo[y])))
            .unwrap_or(0);
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |x, y| x.0[a].total_cmp(&y.0[a]).then(x.1.cmp(&y.1)));
        axis[mid] = a as u8;
        let (left, right) = items.split_at_mut(mid);
        let (al, ar) = axis.split_at_mut(mid);
        Self::build(left, al);
        Self::build(&mut right[1..], &mut ar[1..]);
    }

    /// Squared distance and original index of the nearest point (`None`: empty tree).
    fn nearest(&self, q: [f64; 3]) -> Option<(f64, u32)> {
        let mut best = (f64::INFINITY, usize::MAX);
        self.search(0, self.points.len(), q, &mut best);
        (best.1 != usize::MAX).then(|| (best.0, self.index[best.1]))
    }

    fn search(&self, lo: usize, hi: usize, q: [f64; 3], best: &mut (f64, usize)) {
        let d2 = |p: &[f64; 3]| (0..3).map(|a| (p[a] - q[a]) * (p[a] - q[a])).sum::<f64>();
        if hi - lo <= LEAF {
            for i in lo..hi {
                let d = d2(&self.points[i]);
                if d < best.0 || (d == best.0 && i < best.1) {
                    *best = (d, i);
                }
            }
            return;
        }
        let mid = lo + (hi - lo) / 2;
        let a = self.axis[mid] as usize;
        let p = &self.points[mid];
        let d = d2(p);
        if d < best.0 || (d == best.0 && mid < best.1) {
            *best = (d, mid);
        }
        let diff = q[a] - p[a];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search(near.0, near.1, q, best);
        if diff * diff <= best.0 {
            self.search(far.0, far.1, q, best);
        }
    }
}

/// Distance and nearest index of every `queries` point in `tree`, in query order.
fn distances(tree: &KdTree, queries: &[[f32; 3]]) -> Vec<Option<(f64, u32)>> {
    queries
        .par_iter()
        .with_min_len(256)
        .map(|q| tree.nearest(q.map(f64::from)).map(|(d2, i)| (d2.sqrt(), i)))
        .collect()
}

fn mean(xs: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in xs {
        s += x;
        n += 1;
    }
    if n == 0 { f64::NAN } else { s / n as f64 }
}

/// Scores `mesh`'s vertices (those inside `region`, when given) against `truth`'s points at
/// threshold `tau_m` (module docs).
pub fn score(mesh: &Mesh, truth: &Mesh, tau_m: f64, region: Option<&Region>) -> MeshScore {
    let inside =
        |p: &[f32; 3]| region.is_none_or(|[lo, hi]| (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]));
    let keep: Vec<usize> = (0..mesh.positions.len())
        .filter(|&i| inside(&mesh.positions[i]))
        .collect();
    let vertices_cropped = mesh.positions.len() - keep.len();
    let cropped;
    let mesh = if vertices_cropped == 0 {
        mesh
    } else {
        cropped = Mesh {
            positions: keep.iter().map(|&i| mesh.positions[i]).collect(),
            kelvin: keep
                .iter()
                .map(|&i| mesh.kelvin.get(i).copied().unwrap_or(f32::NAN))
                .collect(),
            ..Mesh::default()
        };
        &cropped
    };
    let to_truth = distances(&KdTree::new(&truth.positions), &mesh.positions);
    let to_mesh = distances(&KdTree::new(&mesh.positions), &truth.positions);
    let (vertices, truth_points) = (mesh.positions.len(), truth.positions.len());
    let both = vertices > 0 && truth_points > 0;
    let nan_unless = |x: f64| if both { x } else { f64::NAN };
    let accuracy_m = nan_unless(mean(to_truth.iter().flatten().map(|d| d.0)));
    let completeness_m = nan_unless(mean(to_mesh.iter().flatten().map(|d| d.0)));
    let within = |ds: &[Option<(f64, u32)>], n: usize| {
        if n == 0 {
            0.0
        } else {
            ds.iter().flatten().filter(|d| d.0 < tau_m).count() as f64 / n as f64
        }
    };
    let precision = within(&to_truth, vertices);
    let recall = within(&to_mesh, truth_points);
    let f_score = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    let kelvin_mae = mean(to_truth.iter().enumerate().filter_map(|(i, d)| {
        let (d, j) = (*d)?;
        let (k, t) = (*mesh.kelvin.get(i)?, *truth.kelvin.get(j as usize)?);
        (d < tau_m && k.is_finite() && t.is_finite()).then(|| f64::from((k - t).abs()))
    }));
    MeshScore {
        tau_m,
        accuracy_m,
        completeness_m,
        chamfer_m: (accuracy_m + completeness_m) / 2.0,
        precision,
        recall,
        f_score,
        kelvin_mae,
        vertices,
        vertices_cropped,
        truth_points,
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use rand::{Rng, SeedableRng};

    use super::*;

    fn cloud(n: usize, seed: u64) -> Mesh {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let positions: Vec<[f32; 3]> = (0..n)
            .map(|_| {
                [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.1..0.1),
                ]
            })
            .collect();
        let kelvin = positions.iter().map(|p| 290.0 + 10.0 * p[0]).collect();
        Mesh {
            positions,
            kelvin,
            ..Mesh::default()
        }
    }

    #[test]
    fn the_tree_finds_the_exact_nearest_point() {
        let truth = cloud(2000, 1);
        let queries = cloud(300, 2);
        let tree = KdTree::new(&truth.positions);
        for q in &queries.positions {
            let brute = truth
                .positions
                .iter()
                .map(|p| {
                    (0..3)
                        .map(|a| (f64::from(p[a]) - f64::from(q[a])).powi(2))
                        .sum::<f64>()
                })
                .fold(f64::INFINITY, f64::min);
            let (d2, i) = tree.nearest(q.map(f64::from)).unwrap();
            assert_eq!(d2, brute, "query {q:?}: tree {d2} vs brute force {brute}");
            let p = truth.positions[i as usize];
            let di = (0..3)
                .map(|a| (f64::from(p[a]) - f64::from(q[a])).powi(2))
                .sum::<f64>();
            assert_eq!(di, d2, "the index is the nearest point's");
        }
        assert!(KdTree::new(&[]).nearest([0.0; 3]).is_none());
    }

    #[test]
    fn a_mesh_against_itself_scores_perfectly() {
        let m = cloud(5000, 3);
        let s = score(&m, &m, 0.01, None);
        assert_eq!(
            (s.accuracy_m, s.completeness_m, s.chamfer_m),
            (0.0, 0.0, 0.0),
            "{s:?}"
        );
        assert_eq!((s.precision, s.recall, s.f_score), (1.0, 1.0, 1.0), "{s:?}");
        assert_eq!(s.kelvin_mae, 0.0, "{s:?}");
        assert_eq!((s.vertices, s.truth_points), (5000, 5000));
    }

    #[test]
    fn vertices_outside_the_evaluation_volume_are_not_scored() {
        let truth = cloud(3000, 7);
        let mut m = truth.clone();
        // A correct surface beyond the scored region (the far ground): left out, not errors.
        for i in 0..500 {
            m.positions.push([3.0 + i as f32 * 1e-3, 0.0, 0.0]);
            m.kelvin.push(250.0);
        }
        let region = [[-1.0, -1.0, -0.1], [1.0, 1.0, 0.1]];
        let s = score(&m, &truth, 0.01, Some(&region));
        assert_eq!(
            (s.vertices, s.vertices_cropped),
            (3000, 500),
            "the 500 vertices 2 m outside the evaluation volume should be cropped, the rest scored"
        );
        assert!(
            s.precision == 1.0 && s.f_score == 1.0 && s.kelvin_mae == 0.0,
            "the cropped mesh is the truth itself: {s:?}"
        );
    }

    #[test]
    fn a_mesh_shifted_by_two_tau_scores_zero() {
        let tau = 0.01;
        // a single plane of points (z = 0), shifted along its normal by 2τ
        let truth = Mesh {
            positions: (0..400)
                .map(|i| [(i % 20) as f32 * 0.005, (i / 20) as f32 * 0.005, 0.0])
                .collect(),
            kelvin: vec![300.0; 400],
            ..Mesh::default()
        };
        let shifted = Mesh {
            positions: truth.positions.iter().map(|p| [p[0], p[1], 0.02]).collect(),
            ..truth.clone()
        };
        let s = score(&shifted, &truth, tau, None);
        assert_eq!((s.precision, s.recall, s.f_score), (0.0, 0.0, 0.0), "{s:?}");
        assert!(
            (s.accuracy_m - 0.02).abs() < 1e-6 && (s.chamfer_m - 0.02).abs() < 1e-6,
            "{s:?}"
        );
        assert!(s.kelvin_mae.is_nan(), "no vertex within τ: {s:?}");
    }

    #[test]
    fn a_one_kelvin_offset_is_a_one_kelvin_error() {
        let truth = cloud(3000, 4);
        let warm = Mesh {
            kelvin: truth.kelvin.iter().map(|k| k + 1.0).collect(),
            ..truth.clone()
        };
        let s = score(&warm, &truth, 0.01, None);
        assert!(
            (s.kelvin_mae - 1.0).abs() < 1e-4,
            "kelvin MAE {} expected 1",
            s.kelvin_mae
        );
        assert_eq!(s.f_score, 1.0);
    }

    #[test]
    fn the_score_is_the_same_on_any_thread_count() {
        let (m, t) = (cloud(4000, 5), cloud(4000, 6));
        let run = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| score(&m, &t, 0.02, None))
        };
        let (a, b) = (run(1), run(3));
        assert_eq!(format!("{a:?}"), format!("{b:?}"), "1 vs 3 threads");
    }
}
