//! Thermal mesh extraction: a trained run's views fused into a sparse truncated signed-distance
//! volume (TSDF), its zero level set extracted by surface nets, written as a PLY with a
//! temperature per vertex, and scored against a simulated scene's truth surface.
//!
//! # Pipeline (`s3tir-train mesh RUN --out mesh.ply`)
//!
//! 1. **Render** every training view: expected depth (camera z, metres; NaN where
//!    alpha < 0.5), temperature in kelvin and, when the run has colour, RGB ([`run`]).
//! 2. **Size**: [`tsdf::Volume::touched_blocks`] lists the blocks within the truncation band
//!    of every view's surface; the voxel grows until they fit the memory budget
//!    ([`tsdf::Volume::bytes_per_block`]).
//! 3. **Fuse** each view, in order, with [`tsdf::Volume::integrate`].
//! 4. **Extract** the mesh with [`extract::extract`].
//! 5. **Write** it with [`plyio::write_mesh_ply`] (and a copy coloured by
//!    [`plyio::thermal_colours`]); **score** it against `truth/surface.ply` with
//!    [`score::score`].
//!
//! # Fusion ([`tsdf`])
//!
//! The volume is sparse: blocks of [`tsdf::BLOCK`]³ = 8³ voxels, allocated only where a view's
//! surface passes within the truncation distance (a hash map from block key to a slot of one
//! flat `Vec<f32>`; nothing is hashed per voxel). Voxel `i` (global integer coordinates) has
//! its centre at `(i + ½)·voxel_m`. Per voxel, as f32: the signed distance in units of the
//! truncation (clamped to `[−1, 1]`, positive in front of surfaces, in free space) and its
//! weight, the mean temperature and its weight, and with colour the mean R, G, B and their
//! weight — 16 or 32 bytes a voxel, 8 or 16 KiB a block.
//!
//! Fusion is **projective**: a voxel centre is projected into the view (pinhole, nearest
//! pixel: column `⌊u + ½⌋`, since pixel `c` covers `u ∈ [c − ½, c + ½]`) and
//! `sdf = depth(pixel) − z_cam(voxel)`. The voxel is skipped when it projects outside the
//! image, behind the camera (`z ≤ 0`), onto a pixel without depth, or lies more than the
//! truncation behind the surface (`sdf < −trunc`: occluded, unknown). Otherwise
//! `tsdf = min(1, sdf/trunc)` joins a running weighted mean. Temperature and colour join their
//! own running means only near the surface (`|sdf| < trunc`), sampled at the same pixel:
//! farther in front the pixel shows a different point of the surface.
//!
//! **Observation weight: the incidence**, `|cos θ|` between the pixel's ray and the normal of
//! the surface it sees (from the back-projected neighbouring pixels), at least
//! [`tsdf::MIN_INCIDENCE_WEIGHT`] = 0.05 ([`tsdf::incidence_weights`]), instead of 1 per
//! observation. A view at grazing incidence measures a projective distance `1/cos θ` times
//! the true one, and near its silhouette the nearest pixel's depth jumps by
//! `footprint·tan θ`; with equal weights these observations drag the zero crossing wherever
//! the set of views changes between neighbouring voxels. Measured on the sphere test (12
//! views, 1 cm voxels): largest vertex error 5.5 → 3.6 mm at 128×96 px, 4.2 → 1.7 mm at
//! 256×192; the 99th percentile of `1 − n·radial` of the normals 2.7× smaller at 128×96, 8×
//! at 256×192. Thermal cameras have the same reason to trust
//! grazing views less (emissivity falls at grazing angles). Weights are therefore
//! "head-on-equivalent observations": `min_weight` 1 asks for one head-on view or e.g. two at
//! 60°.
//!
//! Blocks are updated in parallel on rayon's pool, each voxel on its own; views are fused in
//! order, so the volume is the same bits whatever the thread count. Two cheap tests skip a
//! block: its bounding sphere lies outside the view's frustum, or every pixel its projection
//! can cover has no depth or a depth more than the truncation in front of it (the largest
//! depth per 16×16 pixel tile; the block is hidden or sees no surface).
//!
//! [`tsdf::Volume::touched_blocks`] marks, for each pixel with a depth, the blocks of the voxel
//! centres near the segment of its ray from `depth − trunc` to `depth + trunc` (bounding boxes
//! of pieces no longer than a block, widened by the half-pixel footprint): every voxel the
//! fusion can move within the band is allocated (a missing one would be a hole, see below).
//! The caller passes the set, so sizing allocates nothing per pixel.
//!
//! # Extraction: surface nets ([`mod@extract`])
//!
//! A cell is the cube of 8 voxel centres with min corner voxel `v`. It is **valid** when all 8
//! voxels are allocated and observed with a weight of at least `min_weight` (and above 0,
//! whatever `min_weight`). A voxel edge `(v, v + axis)` is a **crossing** when both ends are
//! observed enough, the sign of the distance changes, and the jump `|tsdf_a − tsdf_b|` is at
//! most [`extract::max_crossing_jump`] = `max(1, 3·voxel/trunc)` (1 at the default truncation
//! of 3 voxels). A genuine surface changes the distance by `voxel/trunc` per voxel times the
//! slope of the projective distance (1 head-on, `1/cos θ` at incidence θ), so 1 allows
//! incidences to ≈ 70°; at an occlusion boundary a voxel just behind a near surface (negative)
//! sits next to a voxel whose pixel sees a far surface (`+1`): the jump is 1 to 2 and the
//! "crossing" is the edge of the occluder's band, not a surface. Rejecting it keeps a skirt of
//! false surface from growing behind the outline of an object seen from one side (test
//! `a_thin_plate_before_a_wall_grows_no_skirt`).
//!
//! Each valid cell with at least one crossing edge gets **one vertex**, at the mean of its
//! crossing edges' linear zero crossings. Each crossing edge whose 4 surrounding cells all
//! have vertices emits a **quad** (two triangles, split along the shorter diagonal), ordered so
//! that its normal points toward positive distance: out of objects, toward the cameras.
//! Vertices are keyed by their global cell, so they are shared across block boundaries (the
//! mesh is welded, and closed wherever the observed region is closed). Unobserved voxels never
//! take part: the back of the truncation band (negative voxels next to unobserved ones) makes
//! no surface, and the mesh ends (open) at the edge of what the views saw.
//!
//! Per vertex: the normal is the area-weighted mean of its triangles' normals (the normalised
//! trilinear gradient of the distance in its cell where that mean vanishes; the gradient
//! alone sees only the 8 corners, and its 99th-percentile error on the sphere test is 3–5×
//! larger); temperature and colour are
//! trilinear interpolations of the fused means over the cell's corners that have a
//! temperature (colour) observation, the weights renormalised over them (NaN kelvin, grey
//! colour, when no corner has one). Vertices no triangle uses are removed. Blocks are
//! processed in key order and combined in that order: the mesh is deterministic and
//! independent of the thread count.
//!
//! **Why not the `fast-surface-nets` crate**: it extracts from dense, padded chunks and treats
//! every sample as observed. Unobserved voxels of a sparse TSDF would then have to be filled
//! with some value: read as "outside" (+1) they make a false surface at the back of every
//! truncation band (the negative voxels behind each surface against the unobserved ones behind
//! them); the alternative is a dense copy of every chunk plus per-sample validity it has no
//! notion of. We also need vertices welded globally across blocks for a closed mesh, the
//! occlusion-jump test on edges, and the temperature interpolated per vertex; the extraction
//! here is a few hundred lines.
//!
//! **Known limits** (tests document them): views coarser than the voxel (a pixel footprint
//! of 2 voxels) cost accuracy (vertices within a voxel rather than half) and can leave
//! pinholes where two grazing pixels' depths differ by more than the truncation (the jump
//! test takes them for occlusion boundaries); behind an object thinner than the truncation,
//! views that see its face (negative) and views that see past its edge (+1) average to a
//! smooth crossing, so a skirt up to the truncation deep can remain behind its outline.
//!
//! # Scoring ([`score`])
//!
//! Exact nearest-neighbour distances between the mesh's vertices and the truth's points (a
//! k-d tree): accuracy (vertex → truth) and completeness (truth → vertex) means, their mean
//! as the Chamfer distance, precision/recall/F-score at `tau_m` (distances strictly below
//! it), and the mean temperature error over the vertices within `tau_m` of the truth.

pub mod error;
pub mod extract;
pub mod plyio;
pub mod score;
pub mod tsdf;

// The command (`s3tir-train mesh`) and its benchmark (`s3tir-train bench --mesh`).
pub mod bench;
pub mod run;

pub use error::MeshError;
pub use extract::{Mesh, extract};
pub use tsdf::{BLOCK, Frame, Volume};

#[cfg(test)]
mod tests;
