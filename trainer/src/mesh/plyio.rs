//! The mesh as a binary PLY with a temperature per vertex, the reader (meshes and point clouds
//! such as the simulator's `truth/surface.ply`), and the ironbow colours of the thermal copy.
//!
//! Written layout (`format binary_little_endian 1.0`, standard property names, so MeshLab,
//! Blender and CloudCompare open it):
//!
//! ```text
//! element vertex N
//! property float x | y | z            world metres
//! property float nx | ny | nz         unit outward normal
//! property float kelvin               temperature, kelvin (NaN: none observed)
//! property uchar red | green | blue   only with colours
//! element face M
//! property list uchar int vertex_indices
//! ```
//!
//! The reader takes any binary little-endian PLY whose vertices have `x y z kelvin` (any
//! numeric type, by name; other properties, lists and other elements are skipped), with
//! `nx ny nz` and `red green blue` when present and faces optional (polygons are split into
//! fans). Every count in the header is checked against the bytes really there before it sizes
//! anything; ASCII and big-endian files are refused with an error naming the file.

use std::fs;
use std::io::Write;
use std::path::Path;

use s3tir_calib::model::palette::Colormap;
use s3tir_calib::model::ply::{self, Body, Element, Header, Prop, Ty};

use super::error::MeshError;
use super::extract::Mesh;

/// The first comment of every mesh written.
pub const MESH_COMMENT: &str =
    "s3tir mesh: surface nets over a fused truncated signed-distance volume";

fn ply_err(path: &Path, reason: impl Into<String>) -> MeshError {
    MeshError::Ply {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Checks that `mesh` (with `colours` replacing its own) can be written as a consistent PLY.
fn check_mesh(path: &Path, mesh: &Mesh, colours: Option<&[[u8; 3]]>) -> Result<(), MeshError> {
    let n = mesh.positions.len();
    let err = |r: String| Err(ply_err(path, r));
    if n > i32::MAX as usize {
        return err(format!(
            "{n} vertices: more than `int` vertex indices address"
        ));
    }
    if mesh.kelvin.len() != n {
        return err(format!(
            "{} temperatures for {n} vertices",
            mesh.kelvin.len()
        ));
    }
    if !(mesh.normals.is_empty() || mesh.normals.len() == n) {
        return err(format!("{} normals for {n} vertices", mesh.normals.len()));
    }
    if let Some(c) = colours.or(mesh.rgb.as_deref())
        && c.len() != n
    {
        return err(format!("{} colours for {n} vertices", c.len()));
    }
    if let Some(i) = mesh
        .positions
        .iter()
        .position(|p| !p.iter().all(|x| x.is_finite()))
    {
        return err(format!(
            "vertex {i}: non-finite position {:?}",
            mesh.positions[i]
        ));
    }
    if let Some(i) = mesh
        .normals
        .iter()
        .position(|p| !p.iter().all(|x| x.is_finite()))
    {
        return err(format!(
            "vertex {i}: non-finite normal {:?}",
            mesh.normals[i]
        ));
    }
    if let Some((t, tri)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&i| i as usize >= n))
    {
        return err(format!(
            "triangle {t} {tri:?}: index beyond the {n} vertices"
        ));
    }
    Ok(())
}

/// Writes `mesh` as a binary little-endian PLY (layout in the module docs), with `colours`
/// replacing the mesh's own colours when given (the colour-mapped thermal copy) and each line
/// of `comment` as a header comment. Built beside `path` as `path.tmp` and renamed into place:
/// a failure leaves an existing `path` as it was.
pub fn write_mesh_ply(
    path: &Path,
    mesh: &Mesh,
    colours: Option<&[[u8; 3]]>,
    comment: &str,
) -> Result<(), MeshError> {
    check_mesh(path, mesh, colours)?;
    let colours = colours.or(mesh.rgb.as_deref());
    let mut comments = vec![MESH_COMMENT.to_owned()];
    comments.extend(comment.lines().map(str::to_owned));
    let mut vertex = Element::scalars(
        "vertex",
        mesh.positions.len(),
        Ty::F32,
        &["x", "y", "z", "nx", "ny", "nz", "kelvin"],
    );
    if colours.is_some() {
        vertex
            .props
            .extend(["red", "green", "blue"].map(|n| Prop::scalar(n, Ty::U8)));
    }
    let face = Element {
        name: "face".into(),
        count: mesh.triangles.len(),
        props: vec![Prop::List {
            name: "vertex_indices".into(),
            count: Ty::U8,
            item: Ty::I32,
        }],
    };
    let header = Header {
        comments,
        elements: vec![vertex, face],
    };
    ply::write_atomic(path, |w| {
        w.write_all(header.text().as_bytes())?;
        for (i, p) in mesh.positions.iter().enumerate() {
            let nrm = mesh.normals.get(i).copied().unwrap_or([0.0; 3]);
            for x in p.iter().chain(&nrm).chain(std::iter::once(&mesh.kelvin[i])) {
                w.write_all(&x.to_le_bytes())?;
            }
            if let Some(c) = colours {
                w.write_all(&c[i])?;
            }
        }
        for t in &mesh.triangles {
            w.write_all(&[3])?;
            for &i in t {
                w.write_all(&(i as i32).to_le_bytes())?;
            }
        }
        Ok(())
    })
    .map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// An axis-aligned evaluation volume: min and max corners, world metres.
pub type Region = [[f32; 3]; 2];

/// The evaluation volume a truth surface states in its header (`comment region_m X0 Y0 Z0 X1
/// Y1 Z1 …`, written by the simulator's `scene::truth`); `None` when it states none.
pub fn read_region(path: &Path) -> Result<Option<Region>, MeshError> {
    let data = fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let (header, _) = Header::read(path, &data)?;
    let Some(line) = header
        .comments
        .iter()
        .find_map(|l| l.strip_prefix("region_m "))
    else {
        return Ok(None);
    };
    let v: Vec<f32> = line
        .split_whitespace()
        .take(6)
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|source| MeshError::PlyNumber {
            path: path.to_path_buf(),
            what: format!("region_m comment `{line}`"),
            source,
        })?;
    match v[..] {
        [x0, y0, z0, x1, y1, z1] if x0 <= x1 && y0 <= y1 && z0 <= z1 => {
            Ok(Some([[x0, y0, z0], [x1, y1, z1]]))
        }
        _ => Err(ply_err(
            path,
            format!("region_m comment `{line}`: expected six numbers, min corner ≤ max corner"),
        )),
    }
}

/// Which vertex properties hold what (indices into a vertex row's scalars).
#[derive(Debug, Clone, Copy)]
struct VertexColumns {
    xyz: [usize; 3],
    kelvin: usize,
    normal: Option<[usize; 3]>,
    rgb: Option<[usize; 3]>,
}

impl VertexColumns {
    /// Finds x, y, z and kelvin (required) and the normal and colour (optional, all three or
    /// none) among `vertex`'s properties; none of them may be a list.
    fn find(path: &Path, vertex: &Element) -> Result<Self, MeshError> {
        let scalar = |name: &str| -> Result<Option<usize>, MeshError> {
            match vertex.props.iter().position(|p| p.name() == name) {
                Some(i) if matches!(vertex.props[i], Prop::List { .. }) => {
                    Err(ply_err(path, format!("vertex property {name} is a list")))
                }
                other => Ok(other),
            }
        };
        let required = |name: &str| {
            scalar(name)?.ok_or_else(|| {
                ply_err(
                    path,
                    format!(
                        "the vertices have no `{name}` property (x, y, z and kelvin are required)"
                    ),
                )
            })
        };
        let xyz = [required("x")?, required("y")?, required("z")?];
        let kelvin = required("kelvin")?;
        let normal = match (scalar("nx")?, scalar("ny")?, scalar("nz")?) {
            (Some(a), Some(b), Some(c)) => Some([a, b, c]),
            _ => None,
        };
        let rgb = match (scalar("red")?, scalar("green")?, scalar("blue")?) {
            (Some(a), Some(b), Some(c)) => Some([a, b, c]),
            _ => None,
        };
        Ok(Self {
            xyz,
            kelvin,
            normal,
            rgb,
        })
    }
}

/// Reads a mesh or a point cloud (module docs for what is read). Errors name the file.
pub fn read_mesh_ply(path: &Path) -> Result<Mesh, MeshError> {
    let data = fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let err = |r: String| ply_err(path, r);
    let (header, start) = Header::read(path, &data)?;
    let vertex = header
        .element("vertex")
        .ok_or_else(|| err("no `element vertex`".into()))?;
    let columns = VertexColumns::find(path, vertex)?;
    let mut body = Body::new(&data[start..]);
    let mut mesh = Mesh {
        rgb: columns.rgb.map(|_| Vec::new()),
        ..Mesh::default()
    };
    // one row's values (scalars; a list leaves an empty slot)
    let mut raw: Vec<(Ty, &[u8])> = Vec::new();
    for el in &header.elements {
        check_fits(path, el, &body)?;
        let is_vertex = std::ptr::eq(el, vertex);
        let face_list = if el.name == "face" {
            Some(face_list_index(path, el)?)
        } else {
            None
        };
        if is_vertex {
            mesh.positions.reserve_exact(el.count);
            mesh.kelvin.reserve_exact(el.count);
        }
        let faces = Faces {
            list: face_list,
            vertices: vertex.count,
        };
        for row in 0..el.count {
            read_row(
                path,
                el,
                row,
                &mut body,
                faces,
                &mut raw,
                &mut mesh.triangles,
            )?;
            if is_vertex {
                push_vertex(path, &mut mesh, &columns, &raw, row)?;
            }
        }
    }
    if body.remaining() != 0 {
        return Err(err(format!(
            "{} bytes after the last element (the header does not describe the data)",
            body.remaining()
        )));
    }
    Ok(mesh)
}

/// An element's rows must fit in the data left, at their smallest (lists empty): checked
/// before any row is read, so a hostile count allocates nothing.
fn check_fits(path: &Path, el: &Element, body: &Body<'_>) -> Result<(), MeshError> {
    let min_row: usize = el.props.iter().map(Prop::min_bytes).sum();
    if el.count > 0 && min_row == 0 {
        return Err(ply_err(
            path,
            format!(
                "element {} has {} rows and no properties",
                el.name, el.count
            ),
        ));
    }
    if el
        .count
        .checked_mul(min_row)
        .is_none_or(|b| b > body.remaining())
    {
        return Err(ply_err(
            path,
            format!(
                "element {}: {} rows of at least {min_row} bytes, but {} bytes of data are left \
                 (truncated file?)",
                el.name,
                el.count,
                body.remaining()
            ),
        ));
    }
    Ok(())
}

/// The face element's vertex-index list property.
fn face_list_index(path: &Path, el: &Element) -> Result<usize, MeshError> {
    el.props
        .iter()
        .position(|p| {
            matches!(
                p,
                Prop::List { name, .. } if name == "vertex_indices" || name == "vertex_index"
            )
        })
        .ok_or_else(|| ply_err(path, "faces without a `vertex_indices` list"))
}

/// Where the face list is in a row (`None`: not the face element) and how many vertices its
/// indices may name.
#[derive(Debug, Clone, Copy)]
struct Faces {
    list: Option<usize>,
    vertices: usize,
}

/// Reads row `row` of `el`: its scalars into `raw` (a list leaves an empty slot), and when it
/// is a face its polygon fanned into `triangles` (indices checked against the vertex count).
fn read_row<'a>(
    path: &Path,
    el: &Element,
    row: usize,
    body: &mut Body<'a>,
    faces: Faces,
    raw: &mut Vec<(Ty, &'a [u8])>,
    triangles: &mut Vec<[u32; 3]>,
) -> Result<(), MeshError> {
    let err = |r: String| ply_err(path, r);
    raw.clear();
    for (pi, p) in el.props.iter().enumerate() {
        let short = || {
            err(format!(
                "element {} row {row}: the data ends (truncated file?)",
                el.name
            ))
        };
        match *p {
            Prop::Scalar { ty, .. } => {
                let b = body.take(ty.size()).ok_or_else(short)?;
                raw.push((ty, b));
            }
            Prop::List { count, item, .. } => {
                let c = count.value(body.take(count.size()).ok_or_else(short)?);
                if c < 0.0 || c.is_nan() {
                    return Err(err(format!(
                        "element {} row {row}: list length {c}",
                        el.name
                    )));
                }
                let c = c as usize;
                let items = c
                    .checked_mul(item.size())
                    .and_then(|b| body.take(b))
                    .ok_or_else(short)?;
                if faces.list == Some(pi) {
                    fan_face(path, row, item, c, items, faces.vertices, triangles)?;
                }
                raw.push((item, &[]));
            }
        }
    }
    Ok(())
}

/// Face `row`'s `c` vertex indices (`items`, of type `item`) fanned into triangles.
fn fan_face(
    path: &Path,
    row: usize,
    item: Ty,
    c: usize,
    items: &[u8],
    n_vertices: usize,
    triangles: &mut Vec<[u32; 3]>,
) -> Result<(), MeshError> {
    let err = |r: String| ply_err(path, r);
    if item.is_float() {
        return Err(err("face vertex indices are not integers".into()));
    }
    if c < 3 {
        return Err(err(format!("face {row}: {c} vertices")));
    }
    let idx = |k: usize| -> Result<u32, MeshError> {
        let v = item.value(&items[k * item.size()..]);
        if v >= 0.0 && v < n_vertices as f64 {
            Ok(v as u32)
        } else {
            Err(err(format!(
                "face {row}: vertex index {v} outside the {n_vertices} vertices"
            )))
        }
    };
    let first = idx(0)?;
    for k in 1..c - 1 {
        triangles.push([first, idx(k)?, idx(k + 1)?]);
    }
    Ok(())
}

/// Appends vertex `row` (its scalars in `raw`) to `mesh`: position (finite), kelvin, and the
/// normal and colour when the file has them (float colours in [0, 1] scaled to bytes).
fn push_vertex(
    path: &Path,
    mesh: &mut Mesh,
    columns: &VertexColumns,
    raw: &[(Ty, &[u8])],
    row: usize,
) -> Result<(), MeshError> {
    let f = |i: usize| raw[i].0.value_f32(raw[i].1);
    let p = columns.xyz.map(f);
    if !p.iter().all(|x| x.is_finite()) {
        return Err(ply_err(
            path,
            format!("vertex {row}: non-finite position {p:?}"),
        ));
    }
    mesh.positions.push(p);
    mesh.kelvin.push(f(columns.kelvin));
    if let Some(nrm) = columns.normal {
        mesh.normals.push(nrm.map(f));
    }
    if let (Some(at), Some(rgb)) = (columns.rgb, mesh.rgb.as_mut()) {
        rgb.push(at.map(|i| {
            let (ty, b) = raw[i];
            let x = ty.value(b);
            let x = if ty.is_float() { x * 255.0 } else { x };
            x.round().clamp(0.0, 255.0) as u8
        }));
    }
    Ok(())
}

/// Ironbow colours of `kelvin` over its 1st–99th percentile range (nearest rank on the
/// finite values; NaN temperatures are mid grey), and that range `(lo, hi)` in kelvin (NaN
/// when no temperature is finite).
pub fn thermal_colours(kelvin: &[f32]) -> (Vec<[u8; 3]>, f32, f32) {
    let lut = Colormap::Ironbow.lut_u8();
    let mut finite: Vec<f32> = kelvin.iter().copied().filter(|k| k.is_finite()).collect();
    if finite.is_empty() {
        return (vec![[128; 3]; kelvin.len()], f32::NAN, f32::NAN);
    }
    finite.sort_unstable_by(f32::total_cmp);
    let rank = |q: f64| finite[((finite.len() - 1) as f64 * q).round() as usize];
    let (lo, hi) = (rank(0.01), rank(0.99));
    let span = hi - lo;
    let colours = kelvin
        .iter()
        .map(|&k| {
            if !k.is_finite() {
                return [128; 3];
            }
            let t = if span > 0.0 { (k - lo) / span } else { 0.5 };
            lut[(t.clamp(0.0, 1.0) * 255.0).round() as usize]
        })
        .collect();
    (colours, lo, hi)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use proptest::prelude::*;

    use super::*;

    fn mesh(colour: bool) -> Mesh {
        Mesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.5, 0.5, 1.0],
            ],
            normals: vec![
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.6, 0.8],
            ],
            kelvin: vec![290.0, 291.5, 300.25, f32::NAN],
            rgb: colour.then(|| vec![[1, 2, 3], [255, 0, 7], [9, 9, 9], [0, 0, 0]]),
            triangles: vec![[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
        }
    }

    /// Equality with NaN temperatures compared by bits.
    fn same(a: &Mesh, b: &Mesh) -> bool {
        let bits = |m: &Mesh| m.kelvin.iter().map(|k| k.to_bits()).collect::<Vec<_>>();
        a.positions == b.positions
            && a.normals == b.normals
            && bits(a) == bits(b)
            && a.rgb == b.rgb
            && a.triangles == b.triangles
    }

    #[test]
    fn meshes_round_trip_with_and_without_colour() {
        let dir = tempfile::tempdir().unwrap();
        for colour in [false, true] {
            let m = mesh(colour);
            let path = dir.path().join(format!("m{colour}.ply"));
            write_mesh_ply(&path, &m, None, "kelvin: test\nsecond line").unwrap();
            let back = read_mesh_ply(&path).unwrap();
            assert!(
                same(&m, &back),
                "round trip (colour {colour}): wrote {m:?}, read {back:?}"
            );
            let text = fs::read(&path).unwrap();
            let header = String::from_utf8_lossy(
                &text[..text.windows(10).position(|w| w == b"end_header").unwrap()],
            )
            .into_owned();
            assert!(
                header.contains("comment kelvin: test\ncomment second line\n"),
                "{header}"
            );
            assert!(
                header.contains("property list uchar int vertex_indices"),
                "{header}"
            );
            assert_eq!(header.contains("property uchar red"), colour, "{header}");
            assert!(
                !dir.path().join(format!("m{colour}.ply.tmp")).exists(),
                "tmp file renamed"
            );
        }
    }

    #[test]
    fn the_colour_mapped_copy_carries_the_palette() {
        let dir = tempfile::tempdir().unwrap();
        let m = mesh(false);
        let (colours, lo, hi) = thermal_colours(&m.kelvin);
        assert_eq!(
            (lo, hi),
            (290.0, 300.25),
            "1st and 99th percentile of 3 finite values"
        );
        let lut = Colormap::Ironbow.lut_u8();
        assert_eq!(
            colours[0], lut[0],
            "the coldest is the palette's first colour"
        );
        assert_eq!(colours[2], lut[255], "the hottest the last");
        assert_eq!(
            colours[1], lut[37],
            "291.5 K is 0.146 of the range: entry 37"
        );
        assert_eq!(colours[3], [128; 3], "no temperature: grey");
        let path = dir.path().join("t.ply");
        write_mesh_ply(&path, &m, Some(&colours), "thermal").unwrap();
        let back = read_mesh_ply(&path).unwrap();
        assert_eq!(
            back.rgb.as_deref(),
            Some(&colours[..]),
            "the palette colours are written"
        );
        assert!(
            same(&Mesh { rgb: None, ..back }, &m),
            "geometry and kelvin unchanged"
        );
        // colours of the wrong length are refused
        let e = write_mesh_ply(&path, &m, Some(&colours[..2]), "").unwrap_err();
        assert!(matches!(e, MeshError::Ply { .. }), "{e}");
    }

    fn truth_bytes(points: &[[f32; 7]]) -> Vec<u8> {
        let mut out = format!(
            "ply\nformat binary_little_endian 1.0\ncomment s3tir truth surface: test\n\
             element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
             property float nx\nproperty float ny\nproperty float nz\nproperty float kelvin\n\
             end_header\n",
            points.len()
        )
        .into_bytes();
        for p in points {
            for x in p {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out
    }

    #[test]
    fn the_simulator_truth_surface_reads_as_a_point_cloud() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("surface.ply");
        let pts = [
            [0.1, 0.2, 0.3, 0.0, 0.0, 1.0, 295.5],
            [1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 310.0],
        ];
        fs::write(&path, truth_bytes(&pts)).unwrap();
        let m = read_mesh_ply(&path).unwrap();
        assert_eq!(m.positions, vec![[0.1, 0.2, 0.3], [1.0, 2.0, 3.0]]);
        assert_eq!(m.normals, vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]);
        assert_eq!(m.kelvin, vec![295.5, 310.0]);
        assert!(m.triangles.is_empty() && m.rgb.is_none());
    }

    #[test]
    fn other_layouts_read_by_name() {
        // doubles, an extra property and a list on the vertices, a quad face, an extra element
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("q.ply");
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\n\
            property double kelvin\nproperty float confidence\nproperty list uchar float junk\n\
            property double z\nproperty double y\nproperty double x\n\
            element face 1\nproperty uchar flags\nproperty list uchar uint vertex_indices\n\
            element edge 1\nproperty int a\nproperty int b\nend_header\n"
            .to_vec();
        for i in 0..4 {
            b.extend_from_slice(&(300.0 + f64::from(i)).to_le_bytes());
            b.extend_from_slice(&1.0f32.to_le_bytes());
            b.push(1);
            b.extend_from_slice(&7.0f32.to_le_bytes());
            for x in [0.0f64, f64::from(i), 2.0 * f64::from(i)] {
                b.extend_from_slice(&x.to_le_bytes());
            }
        }
        b.push(0);
        b.push(4);
        for i in [0u32, 1, 2, 3] {
            b.extend_from_slice(&i.to_le_bytes());
        }
        b.extend_from_slice(&[0; 8]);
        fs::write(&path, &b).unwrap();
        let m = read_mesh_ply(&path).unwrap();
        assert_eq!(
            m.positions[3],
            [6.0, 3.0, 0.0],
            "x y z by name, whatever the order"
        );
        assert_eq!(m.kelvin, vec![300.0, 301.0, 302.0, 303.0]);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]], "the quad as a fan");
        assert!(m.normals.is_empty(), "no normals in the file");
    }

    fn expect_ply_error(path: &Path, bytes: &[u8], want: &str) {
        fs::write(path, bytes).unwrap();
        match read_mesh_ply(path) {
            Err(e @ MeshError::Ply { .. }) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(&path.display().to_string()),
                    "the error names the file: {msg}"
                );
                assert!(msg.contains(want), "expected `{want}` in: {msg}");
            }
            other => panic!("expected MeshError::Ply containing `{want}`, got {other:?}"),
        }
    }

    #[test]
    fn malformed_files_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.ply");
        let good = {
            write_mesh_ply(&path, &mesh(true), None, "").unwrap();
            fs::read(&path).unwrap()
        };
        expect_ply_error(&path, &good[..good.len() - 5], "truncated");
        expect_ply_error(&path, &good[..good.len() - 60], "truncated");
        let mut longer = good.clone();
        longer.push(0);
        expect_ply_error(&path, &longer, "1 bytes after the last element");
        let pts = [[0.0; 7]];
        let t = String::from_utf8_lossy(&truth_bytes(&pts)).into_owned();
        let no_kelvin = truth_bytes(&pts);
        let cut = t.find("property float kelvin\n").unwrap();
        let mut nk = no_kelvin[..cut].to_vec();
        nk.extend_from_slice(
            &no_kelvin[cut + "property float kelvin\n".len()..no_kelvin.len() - 4],
        );
        expect_ply_error(&path, &nk, "no `kelvin` property");
        expect_ply_error(
            &path,
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
              property float z\nproperty float kelvin\nend_header\n0 0 0 300\n",
            "format ascii",
        );
        let be = t.replace("binary_little_endian", "binary_big_endian");
        expect_ply_error(&path, be.as_bytes(), "format binary_big_endian");
        expect_ply_error(&path, b"PK\x03\x04 zip", "not a PLY file");
        expect_ply_error(
            &path,
            b"ply\nformat binary_little_endian 1.0\n",
            "no `end_header`",
        );
        let huge = t.replace("element vertex 1", "element vertex 18446744073709551615");
        expect_ply_error(&path, huge.as_bytes(), "truncated");
        let huge = t.replace("element vertex 1", "element vertex 99999999999999999999999");
        expect_ply_error(&path, huge.as_bytes(), "is not a size");
        // a face index beyond the vertices
        let mut m = mesh(false);
        m.triangles.push([0, 1, 9]);
        let e = write_mesh_ply(&path, &m, None, "").unwrap_err();
        assert!(e.to_string().contains("index beyond"), "{e}");
    }

    #[test]
    fn a_failed_write_leaves_the_existing_file_untouched() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("keep.ply");
        fs::write(&path, b"earlier result").unwrap();
        // the temporary file cannot be created (a folder is in its way)
        fs::create_dir(dir.path().join("keep.ply.tmp")).unwrap();
        let e = write_mesh_ply(&path, &mesh(false), None, "").unwrap_err();
        assert!(matches!(e, MeshError::Io { .. }), "expected Io, got {e}");
        assert_eq!(
            fs::read(&path).unwrap(),
            b"earlier result",
            "the existing file is untouched"
        );
        // a missing folder
        let missing = dir.path().join("no/such/dir/m.ply");
        let e = write_mesh_ply(&missing, &mesh(false), None, "").unwrap_err();
        assert!(
            matches!(&e, MeshError::Io { path, .. } if path.starts_with(dir.path().join("no"))),
            "{e}"
        );
        assert!(!dir.path().join("no").exists());
        // an invalid mesh is refused before anything is written
        let mut bad = mesh(false);
        bad.positions[1][0] = f32::NAN;
        let e = write_mesh_ply(&path, &bad, None, "").unwrap_err();
        assert!(
            e.to_string().contains("vertex 1: non-finite position"),
            "{e}"
        );
        assert_eq!(fs::read(&path).unwrap(), b"earlier result");
    }

    fn valid_mesh_bytes() -> &'static Vec<u8> {
        static V: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
        V.get_or_init(|| {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("v.ply");
            write_mesh_ply(&path, &mesh(true), None, "hostile").unwrap();
            fs::read(&path).unwrap()
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(
            std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
        ))]

        /// Random byte edits (half of them in the header) and cuts of a valid file: the reader
        /// refuses with the file named, or reads no more vertices than the file holds; it never
        /// panics nor allocates from a hostile count.
        #[test]
        fn edited_mesh_files_read_or_fail(
            edits in proptest::collection::vec(
                (any::<proptest::sample::Index>(), any::<bool>(), any::<u8>()),
                1..6,
            ),
            cut in proptest::option::of(any::<proptest::sample::Index>()),
        ) {
            let mut b = valid_mesh_bytes().clone();
            let header = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
            for (at, in_header, byte) in &edits {
                let i = at.index(if *in_header { header } else { b.len() });
                // in the header, half the edits write digits, spaces and line ends
                b[i] = if *in_header && byte % 2 == 0 {
                    b"0123456789 \n"[usize::from(*byte) % 12]
                } else {
                    *byte
                };
            }
            if let Some(c) = cut {
                let i = c.index(b.len() + 1);
                b.truncate(i);
            }
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("e.ply");
            fs::write(&path, &b).unwrap();
            let most = mesh(true).positions.len();
            match read_mesh_ply(&path) {
                // The data holds `most` vertices: a hostile count cannot read more.
                Ok(m) => prop_assert!(
                    m.positions.len() <= most,
                    "{} vertices from a file holding {most}",
                    m.positions.len()
                ),
                Err(e) => {
                    let msg = e.to_string();
                    prop_assert!(msg.contains("e.ply"), "the error names the file: {msg}");
                }
            }
        }
    }
}
