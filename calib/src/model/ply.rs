//! Binary little-endian PLY, the workspace's one PLY codec: the header written and read (every
//! count in it checked against the bytes really there before it sizes anything), the scalar
//! types, a cursor over the body, and the atomic file write. The layouts live with their
//! owners and go through it: the trainer's primitives (`s3tir_trainer::ply`), its meshes
//! (`s3tir_trainer::mesh::plyio`, which also reads point clouds such as the simulator's truth
//! surface) and the simulator's truth surface (`s3tir_firmware_sim::scene::truth`).
//!
//! ASCII and big-endian PLY are refused with an error saying how to convert the file.

use std::fs;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Longest header read (bytes).
pub const MAX_HEADER_BYTES: usize = 1 << 20;

/// A file that is not PLY as this codec reads it; `reason` says where and what.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct FormatError {
    pub path: PathBuf,
    pub reason: String,
}

/// A scalar type of a PLY property.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    /// The type a header names (both the classic and the sized names).
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    /// The classic name, as written.
    pub fn name(self) -> &'static str {
        match self {
            Self::I8 => "char",
            Self::U8 => "uchar",
            Self::I16 => "short",
            Self::U16 => "ushort",
            Self::I32 => "int",
            Self::U32 => "uint",
            Self::F32 => "float",
            Self::F64 => "double",
        }
    }

    /// Bytes of one value.
    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    pub fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }

    /// The value at the start of `b` (`b.len() ≥ size()`).
    pub fn value(self, b: &[u8]) -> f64 {
        match self {
            Self::I8 => f64::from(b[0] as i8),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Self::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Self::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Self::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Self::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Self::F64 => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        }
    }

    /// An `f32` property read exactly (no round trip through f64 for NaN payloads).
    pub fn value_f32(self, b: &[u8]) -> f32 {
        match self {
            Self::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            _ => self.value(b) as f32,
        }
    }
}

/// A property of an element.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Prop {
    Scalar { name: String, ty: Ty },
    List { name: String, count: Ty, item: Ty },
}

impl Prop {
    /// A scalar property.
    pub fn scalar(name: &str, ty: Ty) -> Self {
        Self::Scalar {
            name: name.to_owned(),
            ty,
        }
    }

    pub fn name(&self) -> &str {
        match self {
            Self::Scalar { name, .. } | Self::List { name, .. } => name,
        }
    }

    /// Fewest bytes one value of the property takes.
    pub fn min_bytes(&self) -> usize {
        match self {
            Self::Scalar { ty, .. } => ty.size(),
            Self::List { count, .. } => count.size(),
        }
    }
}

/// An element: its name, row count and properties in file order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Element {
    pub name: String,
    pub count: usize,
    pub props: Vec<Prop>,
}

impl Element {
    /// An element of `count` rows with scalar properties `names`, all of type `ty`.
    pub fn scalars(name: &str, count: usize, ty: Ty, names: &[&str]) -> Self {
        Self {
            name: name.to_owned(),
            count,
            props: names.iter().map(|n| Prop::scalar(n, ty)).collect(),
        }
    }

    /// Bytes of one row when every property is a scalar (`None` with a list).
    pub fn fixed_row_bytes(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p {
                Prop::Scalar { ty, .. } => Some(ty.size()),
                Prop::List { .. } => None,
            })
            .sum()
    }
}

/// A binary little-endian header: comments and elements in file order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Header {
    pub comments: Vec<String>,
    pub elements: Vec<Element>,
}

impl Header {
    /// The header as written, `end_header` line included. Comment lines are single lines
    /// (line breaks in a comment become spaces; empty comments are left out).
    pub fn text(&self) -> String {
        let mut s = String::from("ply\nformat binary_little_endian 1.0\n");
        for c in &self.comments {
            let line = c.replace(['\r', '\n'], " ");
            let line = line.trim();
            if !line.is_empty() {
                s.push_str(&format!("comment {line}\n"));
            }
        }
        for e in &self.elements {
            s.push_str(&format!("element {} {}\n", e.name, e.count));
            for p in &e.props {
                match p {
                    Prop::Scalar { name, ty } => {
                        s.push_str(&format!("property {} {name}\n", ty.name()));
                    }
                    Prop::List { name, count, item } => s.push_str(&format!(
                        "property list {} {} {name}\n",
                        count.name(),
                        item.name()
                    )),
                }
            }
        }
        s.push_str("end_header\n");
        s
    }

    /// The element called `name`.
    pub fn element(&self, name: &str) -> Option<&Element> {
        self.elements.iter().find(|e| e.name == name)
    }

    /// Reads the header at the start of `data` (the file `path`): the header and the offset of
    /// the body. Only binary little-endian files are read.
    pub fn read(path: &Path, data: &[u8]) -> Result<(Header, usize), FormatError> {
        let err = |reason: String| FormatError {
            path: path.to_path_buf(),
            reason,
        };
        let mut pos = 0;
        let mut header = Header::default();
        let mut first = true;
        let mut format = false;
        loop {
            if pos >= data.len().min(MAX_HEADER_BYTES) {
                return Err(err(format!(
                    "no `end_header` line in the first {} bytes",
                    data.len().min(MAX_HEADER_BYTES)
                )));
            }
            let end = data[pos..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(data.len(), |e| pos + e);
            let line = std::str::from_utf8(&data[pos..end])
                .map_err(|_| err(format!("header byte {pos}: not text")))?
                .trim_end_matches('\r');
            pos = (end + 1).min(data.len());
            if first {
                if line != "ply" {
                    return Err(err("not a PLY file (no `ply` first line)".into()));
                }
                first = false;
                continue;
            }
            let t: Vec<&str> = line.split_whitespace().collect();
            match t.as_slice() {
                ["end_header"] => break,
                ["comment", ..] => {
                    let text = line.trim_start().strip_prefix("comment").unwrap_or("");
                    header.comments.push(text.trim().to_owned());
                }
                ["obj_info", ..] | [] => {}
                ["format", "binary_little_endian", _] => format = true,
                ["format", f, ..] => {
                    return Err(err(format!(
                        "format {f}: only binary_little_endian PLY is read (convert the file, \
                         e.g. in MeshLab or CloudCompare)"
                    )));
                }
                ["element", name, n] => {
                    let count = n
                        .parse::<u64>()
                        .ok()
                        .and_then(|c| usize::try_from(c).ok())
                        .ok_or_else(|| err(format!("element {name}: count `{n}` is not a size")))?;
                    header.elements.push(Element {
                        name: (*name).to_owned(),
                        count,
                        props: Vec::new(),
                    });
                }
                ["property", "list", c, i, name] => {
                    let (Some(count), Some(item)) = (Ty::parse(c), Ty::parse(i)) else {
                        return Err(err(format!("property list {c} {i} {name}: unknown type")));
                    };
                    if count.is_float() {
                        return Err(err(format!(
                            "property list {name}: count type {c} is not an integer"
                        )));
                    }
                    header
                        .elements
                        .last_mut()
                        .ok_or_else(|| err(format!("property {name} before any element")))?
                        .props
                        .push(Prop::List {
                            name: (*name).to_owned(),
                            count,
                            item,
                        });
                }
                ["property", ty, name] => {
                    let ty = Ty::parse(ty)
                        .ok_or_else(|| err(format!("property {name}: unknown type {ty}")))?;
                    header
                        .elements
                        .last_mut()
                        .ok_or_else(|| err(format!("property {name} before any element")))?
                        .props
                        .push(Prop::Scalar {
                            name: (*name).to_owned(),
                            ty,
                        });
                }
                _ => return Err(err(format!("header line `{line}` is not PLY"))),
            }
        }
        if !format {
            return Err(err("no `format` line".into()));
        }
        Ok((header, pos))
    }
}

/// The body as a cursor.
#[derive(Debug)]
pub struct Body<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Body<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0 }
    }

    /// The next `n` bytes, `None` past the end.
    pub fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let s = self.data.get(self.pos..self.pos.checked_add(n)?)?;
        self.pos += n;
        Some(s)
    }

    /// Bytes not yet taken.
    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }
}

/// `path` + `.tmp` in the same folder (`None`: `path` names no file).
pub fn tmp_path(path: &Path) -> Option<PathBuf> {
    let mut name = path.file_name()?.to_os_string();
    name.push(".tmp");
    Some(path.with_file_name(name))
}

/// Writes a file through `write` atomically: into `path.tmp` (see [`tmp_path`]), synced, then
/// renamed over `path`; on failure the temporary file is removed and an existing `path` is
/// left as it was.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<fs::File>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let tmp = tmp_path(path)
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file path"))?;
    let done = (|| {
        let mut w = BufWriter::with_capacity(1 << 20, fs::File::create(&tmp)?);
        write(&mut w)?;
        let f = w.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        drop(f);
        fs::rename(&tmp, path)
    })();
    if done.is_err() {
        // Best effort: the error to report is the write's.
        let _ = fs::remove_file(&tmp);
    }
    done
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// What [`Header::text`] writes, [`Header::read`] reads back, with the body's offset.
    #[test]
    fn a_written_header_reads_back() {
        let mut vertex = Element::scalars("vertex", 2, Ty::F32, &["x", "y", "z"]);
        vertex.props.push(Prop::scalar("red", Ty::U8));
        let face = Element {
            name: "face".into(),
            count: 1,
            props: vec![Prop::List {
                name: "vertex_indices".into(),
                count: Ty::U8,
                item: Ty::I32,
            }],
        };
        let header = Header {
            comments: vec!["made by a test".into(), "region_m 0 0 0 1 1 1".into()],
            elements: vec![vertex, face],
        };
        let mut data = header.text().into_bytes();
        let at = data.len();
        data.extend_from_slice(&[0; 4]);
        let (read, body) = Header::read(Path::new("t.ply"), &data).unwrap();
        assert_eq!(read, header, "the header read back");
        assert_eq!(body, at, "the body starts after end_header");
        assert_eq!(
            header.elements[0].fixed_row_bytes(),
            Some(13),
            "3 floats + 1 uchar"
        );
        assert_eq!(
            header.elements[1].fixed_row_bytes(),
            None,
            "a list has no fixed size"
        );
    }

    #[test]
    fn other_formats_are_refused_with_the_file_named() {
        for (text, want) in [
            (
                "ply\nformat ascii 1.0\nend_header\n",
                "only binary_little_endian",
            ),
            ("plx\n", "not a PLY file"),
            ("ply\nelement vertex -1\n", "is not a size"),
            (
                "ply\nformat binary_little_endian 1.0\nelement v 1\nproperty half x\n",
                "unknown type",
            ),
            ("ply\nformat binary_little_endian 1.0\n", "no `end_header`"),
        ] {
            let e = Header::read(Path::new("bad.ply"), text.as_bytes()).unwrap_err();
            let msg = e.to_string();
            assert!(
                msg.contains(want) && msg.contains("bad.ply"),
                "{text:?}: {msg}"
            );
        }
    }
}
