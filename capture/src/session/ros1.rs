//! The ROS 1 message codec of the image topics: `sensor_msgs/Image` and
//! `sensor_msgs/CompressedImage` schemas, serialization and parsing.

const HEADER_DEF: &str = "================================================================================\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n";

pub(crate) fn image_schema() -> String {
    format!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n{HEADER_DEF}"
    )
}

pub(crate) fn compressed_schema() -> String {
    format!("std_msgs/Header header\nstring format\nuint8[] data\n{HEADER_DEF}")
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    put_u32(out, s.len() as u32);
    out.extend_from_slice(s.as_bytes());
}

fn put_header(out: &mut Vec<u8>, seq: u32, wall_unix_ns: u64, frame_id: &str) {
    put_u32(out, seq);
    put_u32(out, (wall_unix_ns / 1_000_000_000) as u32);
    put_u32(out, (wall_unix_ns % 1_000_000_000) as u32);
    put_str(out, frame_id);
}

/// `sensor_msgs/Image` in ROS 1 serialization (`img.seq` is the header's `seq`).
pub fn encode_ros_image(img: &RosImage<'_>, wall_unix_ns: u64, frame_id: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 + img.data.len());
    put_header(&mut out, img.seq, wall_unix_ns, frame_id);
    put_u32(&mut out, img.height);
    put_u32(&mut out, img.width);
    put_str(&mut out, img.encoding);
    out.push(0); // is_bigendian
    put_u32(&mut out, img.step);
    put_u32(&mut out, img.data.len() as u32);
    out.extend_from_slice(img.data);
    out
}

/// `sensor_msgs/CompressedImage` in ROS 1 serialization.
pub fn encode_ros_compressed(seq: u32, wall_unix_ns: u64, frame_id: &str, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(48 + data.len());
    put_header(&mut out, seq, wall_unix_ns, frame_id);
    put_str(&mut out, "jpeg");
    put_u32(&mut out, data.len() as u32);
    out.extend_from_slice(data);
    out
}

struct Cursor<'a> {
    buf: &'a [u8],
}

impl<'a> Cursor<'a> {
    fn u32(&mut self) -> Option<u32> {
        let (h, t) = self.buf.split_first_chunk::<4>()?;
        self.buf = t;
        Some(u32::from_le_bytes(*h))
    }
    fn bytes(&mut self, n: usize) -> Option<&'a [u8]> {
        if self.buf.len() < n {
            return None;
        }
        let (h, t) = self.buf.split_at(n);
        self.buf = t;
        Some(h)
    }
    fn sized(&mut self) -> Option<&'a [u8]> {
        let n = self.u32()? as usize;
        self.bytes(n)
    }
}

/// Decoded `sensor_msgs/Image` fields this crate needs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RosImage<'a> {
    pub seq: u32,
    pub width: u32,
    pub height: u32,
    pub encoding: &'a str,
    pub step: u32,
    pub data: &'a [u8],
}

pub fn decode_ros_image(buf: &[u8]) -> Option<RosImage<'_>> {
    let mut c = Cursor { buf };
    let seq = c.u32()?;
    c.bytes(8)?;
    c.sized()?;
    let height = c.u32()?;
    let width = c.u32()?;
    let encoding = std::str::from_utf8(c.sized()?).ok()?;
    c.bytes(1)?;
    let step = c.u32()?;
    let data = c.sized()?;
    Some(RosImage {
        seq,
        width,
        height,
        encoding,
        step,
        data,
    })
}

/// Returns (seq, format, data) of a `sensor_msgs/CompressedImage`.
pub fn decode_ros_compressed(buf: &[u8]) -> Option<(u32, &str, &[u8])> {
    let mut c = Cursor { buf };
    let seq = c.u32()?;
    c.bytes(8)?;
    c.sized()?;
    let format = std::str::from_utf8(c.sized()?).ok()?;
    let data = c.sized()?;
    Some((seq, format, data))
}
