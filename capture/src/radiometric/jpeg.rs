//! The FFF inside a FLIR radiometric JPEG: APP1 segments whose payload starts `FLIR\0`, then a
//! byte 1, the chunk's index and the last chunk's index, then up to 64 KiB of the FFF. The
//! chunks are read up to the start of the scan and joined in index order.

use super::RadiometricError;

/// The FFF bytes of the JPEG `bytes` (an error if it has no FLIR segment or a chunk is missing).
pub fn fff_from_jpeg(bytes: &[u8]) -> Result<Vec<u8>, RadiometricError> {
    let bad = |reason: String| RadiometricError::format("radiometric JPEG", reason);
    if !bytes.starts_with(&[0xff, 0xd8]) {
        return Err(bad("not a JPEG (no start-of-image marker)".into()));
    }
    let mut chunks: Vec<Option<&[u8]>> = Vec::new();
    let mut at = 2;
    while at + 4 <= bytes.len() {
        if bytes[at] != 0xff {
            return Err(bad(format!("no marker at byte {at:#x}")));
        }
        let marker = bytes[at + 1];
        if marker == 0xff {
            at += 1; // fill byte
            continue;
        }
        if marker == 0xda || marker == 0xd9 {
            break; // start of scan / end of image: no metadata after it
        }
        if (0xd0..=0xd7).contains(&marker) || marker == 0x01 {
            at += 2;
            continue;
        }
        let len = usize::from(u16::from_be_bytes([bytes[at + 2], bytes[at + 3]]));
        let Some(payload) = bytes.get(at + 4..at + 2 + len).filter(|_| len >= 2) else {
            return Err(bad(format!(
                "segment {marker:#04x} at {at:#x} of {len} bytes runs past the file's end ({} bytes)",
                bytes.len()
            )));
        };
        if marker == 0xe1 && payload.starts_with(b"FLIR\0") && payload.len() >= 8 {
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
        at += 2 + len;
    }
    if chunks.is_empty() {
        return Err(bad(
            "no FLIR segment: not a radiometric JPEG (an 8-bit picture has no temperatures)".into(),
        ));
    }
    let mut fff = Vec::new();
    for (k, c) in chunks.iter().enumerate() {
        let c = c.ok_or_else(|| bad(format!("FLIR chunk {k} of {} is missing", chunks.len())))?;
        fff.extend_from_slice(c);
    }
    Ok(fff)
}
