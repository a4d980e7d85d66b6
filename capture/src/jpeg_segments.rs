//! A JPEG's marker segments before its scan (where EXIF, XMP and FLIR's radiometric data
//! live): the one walker of JPEG structure, used by [`crate::radiometric`] and
//! [`crate::image_meta`]. Bounded by the file: a length past its end is an error.

/// One segment: its marker (0xe1 for APP1, …) and payload (after the length).
#[derive(Debug, Clone, Copy)]
pub struct Segment<'a> {
    pub marker: u8,
    pub payload: &'a [u8],
}

/// The segments of `bytes` up to the start of scan (or the end of the image); `Err` says what
/// is wrong (not a JPEG, a marker missing, a length past the end).
pub fn segments(bytes: &[u8]) -> Result<Vec<Segment<'_>>, String> {
    if !bytes.starts_with(&[0xff, 0xd8]) {
        return Err("not a JPEG (no start-of-image marker)".into());
    }
    let mut out = Vec::new();
    let mut at = 2;
    while at + 4 <= bytes.len() {
        if bytes[at] != 0xff {
            return Err(format!("no marker at byte {at:#x}"));
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
            return Err(format!(
                "segment {marker:#04x} at {at:#x} of {len} bytes runs past the file's end ({} bytes)",
                bytes.len()
            ));
        };
        out.push(Segment { marker, payload });
        at += 2 + len;
    }
    Ok(out)
}
