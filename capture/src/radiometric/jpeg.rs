//! The FFF inside a FLIR radiometric JPEG: APP1 segments whose payload starts `FLIR\0`, then a
//! byte 1, the chunk's index and the last chunk's index, then up to 64 KiB of the FFF. The
//! chunks are read up to the start of the scan ([`crate::jpeg_segments`]) and joined in index
//! order.

use super::RadiometricError;

/// The FFF bytes of the JPEG `bytes`: `None` when it has no FLIR segment (an ordinary picture),
/// an error when a chunk is missing or the JPEG is damaged.
pub fn fff_from_jpeg(bytes: &[u8]) -> Result<Option<Vec<u8>>, RadiometricError> {
    let bad = |reason: String| RadiometricError::format("radiometric JPEG", reason);
    let mut chunks: Vec<Option<&[u8]>> = Vec::new();
    for seg in crate::jpeg_segments::segments(bytes).map_err(bad)? {
        let payload = seg.payload;
        if seg.marker == 0xe1 && payload.starts_with(b"FLIR\0") && payload.len() >= 8 {
            let (index, last) = (usize::from(payload[6]), usize::from(payload[7]));
            if index > last {
                return Err(bad(format!("FLIR chunk {index} of {}", last + 1)));
            }
            if chunks.is_empty() {
                chunks.resize(last + 1, None);
            } else if chunks.len() != last + 1 {
                return Err(bad(format!(
                    "FLIR chunks disagree on their count ({} and {})",
                    chunks.len(),
                    last + 1
                )));
            }
            chunks[index] = Some(&payload[8..]);
        }
    }
    if chunks.is_empty() {
        return Ok(None);
    }
    let mut fff = Vec::new();
    for (k, c) in chunks.iter().enumerate() {
        let c = c.ok_or_else(|| bad(format!("FLIR chunk {k} of {} is missing", chunks.len())))?;
        fff.extend_from_slice(c);
    }
    Ok(Some(fff))
}
