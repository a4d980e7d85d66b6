//! Chunk decoding with checked sizes: LZ4 decompression, CRC check and the split into
//! records, every claimed length checked before memory is reserved for it.

use std::io::Read;

use mcap::records::Record;

/// Largest record the reader accepts (a chunk holds at most
/// ~[`MAX_CHUNK_BYTES`](crate::session::writer::MAX_CHUNK_BYTES) plus one frame; a 4K YUYV
/// frame is 16.6 MB).
pub const MAX_RECORD_BYTES: usize = 256 * 1024 * 1024;
/// LZ4 cannot expand data by more than about 255× (a match encodes at most 255 bytes per
/// length byte); a chunk claiming more than this times its compressed size is damaged.
pub const LZ4_MAX_RATIO: u64 = 256;
/// A record's opcode byte and u64 length.
pub(crate) const RECORD_PREFIX_LEN: u64 = 9;

/// Why a chunk cannot be used (the reader stops at it and says why).
#[derive(Debug, thiserror::Error)]
pub enum ChunkError {
    #[error("header says {header} compressed bytes, the record holds {held}")]
    CompressedSize { header: u64, held: usize },
    #[error("claims {claimed} uncompressed bytes, more than the {MAX_RECORD_BYTES}-byte limit")]
    TooLarge { claimed: u64 },
    #[error("uncompressed chunk of {held} bytes claims {claimed}")]
    UncompressedSize { held: usize, claimed: u64 },
    #[error("claims {claimed} bytes from {held} LZ4 bytes (LZ4 expands at most {LZ4_MAX_RATIO}x)")]
    Lz4Ratio { claimed: u64, held: usize },
    #[error("lz4")]
    Lz4 {
        #[source]
        source: std::io::Error,
    },
    #[error("decompresses to {got} bytes, the header claims {claimed}")]
    DecompressedSize { got: usize, claimed: u64 },
    #[error("compression {name:?} (sessions use lz4)")]
    Compression { name: String },
    #[error("CRC {computed:#010x} of the records, the header says {header:#010x}")]
    Crc { computed: u32, header: u32 },
    #[error("record header at chunk byte {at} cut ({left} bytes left)")]
    RecordHeaderCut { at: usize, left: usize },
    #[error("record (opcode {opcode:#04x}) at chunk byte {at} claims {len} bytes, {left} are left")]
    RecordLength {
        opcode: u8,
        at: usize,
        len: u64,
        left: usize,
    },
    #[error("record (opcode {opcode:#04x}) at chunk byte {at}")]
    Record {
        opcode: u8,
        at: usize,
        #[source]
        source: mcap::McapError,
    },
}

/// Decompresses one chunk's records and checks its CRC. Every claimed size is checked against
/// [`MAX_RECORD_BYTES`] and the bytes really present before memory is reserved for it.
pub fn decode_chunk(
    header: &mcap::records::ChunkHeader,
    data: &[u8],
) -> Result<Vec<u8>, ChunkError> {
    let claimed = header.uncompressed_size;
    if data.len() as u64 != header.compressed_size {
        return Err(ChunkError::CompressedSize {
            header: header.compressed_size,
            held: data.len(),
        });
    }
    if claimed > MAX_RECORD_BYTES as u64 {
        return Err(ChunkError::TooLarge { claimed });
    }
    let body = match header.compression.as_str() {
        "" => {
            if claimed != data.len() as u64 {
                return Err(ChunkError::UncompressedSize {
                    held: data.len(),
                    claimed,
                });
            }
            data.to_vec()
        }
        "lz4" => {
            if claimed > (data.len() as u64).saturating_mul(LZ4_MAX_RATIO) {
                return Err(ChunkError::Lz4Ratio {
                    claimed,
                    held: data.len(),
                });
            }
            let mut body = Vec::with_capacity(claimed as usize);
            let decoder = lz4::Decoder::new(data).map_err(|source| ChunkError::Lz4 { source })?;
            // One byte more than claimed is read so a longer stream is seen, not cut.
            decoder
                .take(claimed + 1)
                .read_to_end(&mut body)
                .map_err(|source| ChunkError::Lz4 { source })?;
            if body.len() as u64 != claimed {
                return Err(ChunkError::DecompressedSize {
                    got: body.len(),
                    claimed,
                });
            }
            body
        }
        other => {
            return Err(ChunkError::Compression {
                name: other.to_owned(),
            });
        }
    };
    if header.uncompressed_crc != 0 {
        let crc = crc32fast::hash(&body);
        if crc != header.uncompressed_crc {
            return Err(ChunkError::Crc {
                computed: crc,
                header: header.uncompressed_crc,
            });
        }
    }
    Ok(body)
}

/// Splits a decompressed chunk into records; a record claiming more bytes than the chunk has
/// left is an error, not an allocation.
pub fn split_chunk(body: &[u8]) -> Result<Vec<Record<'static>>, ChunkError> {
    let mut recs = Vec::new();
    let mut rest = body;
    let mut at = 0usize;
    while !rest.is_empty() {
        let Some((&opcode, tail)) = rest.split_first() else {
            break;
        };
        let Some((len, tail)) = tail.split_first_chunk::<8>() else {
            return Err(ChunkError::RecordHeaderCut {
                at,
                left: rest.len(),
            });
        };
        let len = u64::from_le_bytes(*len);
        if len > tail.len() as u64 {
            return Err(ChunkError::RecordLength {
                opcode,
                at,
                len,
                left: tail.len(),
            });
        }
        let (data, tail) = tail.split_at(len as usize);
        let rec = mcap::parse_record(opcode, data).map_err(|source| ChunkError::Record {
            opcode,
            at,
            source,
        })?;
        recs.push(rec.into_owned());
        at += RECORD_PREFIX_LEN as usize + data.len();
        rest = tail;
    }
    Ok(recs)
}
