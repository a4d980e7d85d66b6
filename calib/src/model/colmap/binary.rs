//! COLMAP's binary files (`cameras.bin`, `images.bin`, `points3D.bin`, little-endian):
//! every count checked against the bytes left (a hostile count is an error, not an allocation);
//! errors name the file and the byte or record.

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use super::{
    At, ColmapError, ColmapModel, colmap_camera, image_record, model_name, open_error, param_count,
    point_record,
};

/// Little-endian cursor over a binary COLMAP file.
struct Cursor<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], ColmapError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(ColmapError::Parse {
                path: self.path.to_path_buf(),
                line: 0,
                reason: format!("truncated at byte {} (wanted {n} more)", self.pos),
            });
        };
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn arr<const N: usize>(&mut self) -> Result<[u8; N], ColmapError> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }
    fn u64(&mut self) -> Result<u64, ColmapError> {
        Ok(u64::from_le_bytes(self.arr()?))
    }
    fn i32(&mut self) -> Result<i32, ColmapError> {
        Ok(i32::from_le_bytes(self.arr()?))
    }
    fn f64(&mut self) -> Result<f64, ColmapError> {
        Ok(f64::from_le_bytes(self.arr()?))
    }
    fn u8(&mut self) -> Result<u8, ColmapError> {
        Ok(self.arr::<1>()?[0])
    }
    fn count(&mut self, elem_bytes: usize) -> Result<usize, ColmapError> {
        let n = self.u64()?;
        // A count that cannot fit in the rest of the file is corruption, not an allocation.
        let remaining = (self.data.len() - self.pos) as u64;
        if n.saturating_mul(elem_bytes as u64) > remaining {
            return Err(ColmapError::Parse {
                path: self.path.to_path_buf(),
                line: 0,
                reason: format!("count {n} at byte {} exceeds the file", self.pos - 8),
            });
        }
        Ok(n as usize)
    }
}

fn read_bytes(path: &Path, what: &'static str) -> Result<Vec<u8>, ColmapError> {
    let mut f = fs::File::open(path).map_err(open_error(path, what))?;
    let mut v = Vec::new();
    f.read_to_end(&mut v).map_err(|e| ColmapError::Io {
        path: path.to_path_buf(),
        source: e,
    })?;
    Ok(v)
}

/// Reads `cameras.bin`, `images.bin`, `points3D.bin` (the last may be missing).
pub fn read_binary_model(dir: &Path) -> Result<ColmapModel, ColmapError> {
    let mut model = ColmapModel::default();
    let path: PathBuf = dir.join("cameras.bin");
    let data = read_bytes(&path, "COLMAP cameras.bin")?;
    let mut c = Cursor {
        path: &path,
        data: &data,
        pos: 0,
    };
    let n = c.count(24)?;
    for _ in 0..n {
        let id = c.i32()?;
        let model_id = c.i32()?;
        let width = c.u64()?;
        let height = c.u64()?;
        let name = model_name(model_id);
        let Some(np) = param_count(model_id) else {
            return Err(ColmapError::UnsupportedCameraModel {
                path: path.clone(),
                model: name,
            });
        };
        let params = (0..np).map(|_| c.f64()).collect::<Result<Vec<_>, _>>()?;
        model.cameras.push(colmap_camera(
            &path, 0, id as u32, &name, width, height, &params,
        )?);
    }

    let path: PathBuf = dir.join("images.bin");
    let data = read_bytes(&path, "COLMAP images.bin")?;
    let mut c = Cursor {
        path: &path,
        data: &data,
        pos: 0,
    };
    let n = c.count(64)?;
    for _ in 0..n {
        let id = c.i32()?;
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = c.f64()?;
        }
        let camera_id = c.i32()?;
        let mut name = Vec::new();
        loop {
            let b = c.u8()?;
            if b == 0 {
                break;
            }
            name.push(b);
        }
        let np = c.count(24)?;
        c.take(np * 24)?;
        let name = String::from_utf8_lossy(&name).into_owned();
        let at = At {
            path: &path,
            line: 0,
        };
        let image = image_record(at, id as u32, camera_id as u32, name, v)?;
        model.images.push(image);
    }

    let path: PathBuf = dir.join("points3D.bin");
    if path.exists() {
        let data = read_bytes(&path, "COLMAP points3D.bin")?;
        let mut c = Cursor {
            path: &path,
            data: &data,
            pos: 0,
        };
        let n = c.count(43)?;
        for _ in 0..n {
            let id = c.u64()?;
            let xyz = [c.f64()?, c.f64()?, c.f64()?];
            let rgb = [c.u8()?, c.u8()?, c.u8()?];
            let _error = c.f64()?;
            let track = c.count(8)?;
            c.take(track * 8)?;
            let at = At {
                path: &path,
                line: 0,
            };
            model.points.push(point_record(at, id, xyz, rgb)?);
        }
    }
    Ok(model)
}
