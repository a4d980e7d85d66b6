//! The EXIF fields s3tir uses, through `kamadak-exif`.

use ::exif::{In, Reader, Tag, Value};

use super::{GeoPosition, ImageMeta};

/// The EXIF fields of `bytes` (a JPEG, TIFF, PNG, WebP or HEIF container); a file without EXIF
/// is empty metadata, damaged EXIF an error.
pub fn read(bytes: &[u8]) -> Result<ImageMeta, String> {
    let exif = match Reader::new().read_from_container(&mut std::io::Cursor::new(bytes)) {
        Ok(e) => e,
        Err(::exif::Error::NotFound(_)) => return Ok(ImageMeta::default()),
        // Not a container kamadak-exif knows (e.g. a bare FFF): no EXIF.
        Err(::exif::Error::InvalidFormat(why)) if why.contains("Unknown image format") => {
            return Ok(ImageMeta::default());
        }
        Err(e) => return Err(e.to_string()),
    };
    let field = |tag: Tag| exif.get_field(tag, In::PRIMARY).map(|f| &f.value);
    let text = |tag: Tag| match field(tag) {
        Some(Value::Ascii(v)) => v
            .first()
            .map(|s| String::from_utf8_lossy(s).trim().to_string())
            .filter(|s| !s.is_empty()),
        _ => None,
    };
    let number = |tag: Tag| match field(tag) {
        Some(Value::Rational(v)) => v.first().map(|r| r.to_f64()),
        Some(Value::SRational(v)) => v.first().map(|r| r.to_f64()),
        Some(Value::Short(v)) => v.first().map(|&x| f64::from(x)),
        Some(Value::Long(v)) => v.first().map(|&x| f64::from(x)),
        _ => None,
    };
    let whole = |tag: Tag| number(tag).filter(|x| *x >= 0.0).map(|x| x as u32);
    // degrees, minutes, seconds → signed degrees by the reference letter
    let angle = |tag: Tag, reference: Tag, negative: u8| -> Option<f64> {
        let Some(Value::Rational(dms)) = field(tag) else {
            return None;
        };
        let deg = dms
            .iter()
            .zip([1.0, 60.0, 3600.0])
            .map(|(r, div)| r.to_f64() / div)
            .sum::<f64>();
        let sign = match field(reference) {
            Some(Value::Ascii(v)) if v.first().and_then(|s| s.first()) == Some(&negative) => -1.0,
            _ => 1.0,
        };
        deg.is_finite().then_some(sign * deg)
    };
    let gps_exif = match (
        angle(Tag::GPSLatitude, Tag::GPSLatitudeRef, b'S'),
        angle(Tag::GPSLongitude, Tag::GPSLongitudeRef, b'W'),
    ) {
        (Some(latitude_deg), Some(longitude_deg)) => Some(GeoPosition {
            latitude_deg,
            longitude_deg,
            altitude_m: number(Tag::GPSAltitude).map(|a| match field(Tag::GPSAltitudeRef) {
                Some(Value::Byte(v)) if v.first() == Some(&1) => -a,
                _ => a,
            }),
        }),
        _ => None,
    };
    let capture_time = text(Tag::DateTimeOriginal).map(|t| match text(Tag::SubSecTimeOriginal) {
        Some(sub) => format!("{t}.{sub}"),
        None => t,
    });
    Ok(ImageMeta {
        make: text(Tag::Make),
        model: text(Tag::Model),
        capture_time,
        width: whole(Tag::PixelXDimension),
        height: whole(Tag::PixelYDimension),
        focal_length_mm: number(Tag::FocalLength),
        focal_length_35mm: number(Tag::FocalLengthIn35mmFilm),
        gps_exif,
        ..ImageMeta::default()
    })
}
