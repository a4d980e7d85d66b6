//! Proves the metadata reader on real drone images against ExifTool: every one of the 93
//! thermal-facade JPEGs (DJI Mavic 2 Enterprise Dual) reads the camera, capture time, size,
//! EXIF GPS, DJI's XMP GPS, altitudes and gimbal and flight angles that ExifTool reads
//! (`tests/data/exiftool/`); a JPEG without metadata (sun-board's) is empty metadata, not an
//! error; damaged EXIF or XMP is an error naming the file and the part.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use s3tir_capture::image_meta::{ImageMeta, MetaError};

/// A real data set in `shared/data/` (beside the clone, or under `$S3TIR_SHARED_DIR`).
fn shared_data(set: &str) -> PathBuf {
    std::env::var_os("S3TIR_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data")
        .join(set)
}

/// ExifTool's CSV: one map per image, column → text.
fn exiftool_rows() -> Vec<HashMap<String, String>> {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/exiftool/thermal-facade.csv"),
    )
    .unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    lines
        .map(|l| {
            header
                .iter()
                .zip(l.split(','))
                .map(|(h, v)| (h.to_string(), v.to_string()))
                .collect()
        })
        .collect()
}

#[test]
fn every_facade_image_reads_as_exiftool_reads_it() {
    let images = shared_data("thermal-facade/images");
    let rows = exiftool_rows();
    assert_eq!(rows.len(), 93, "ExifTool's dump has the 93 images");
    for row in &rows {
        let name = &row["SourceFile"];
        let m = ImageMeta::read(&images.join(name))
            .unwrap_or_else(|e| panic!("{name}: {}", s3tir_capture::Chain(&e)));
        let num = |col: &str| -> f64 { row[col].parse().unwrap() };
        assert_eq!(m.make.as_deref(), Some(row["IFD0:Make"].as_str()), "{name}");
        assert_eq!(
            m.model.as_deref(),
            Some(row["IFD0:Model"].as_str()),
            "{name}"
        );
        assert_eq!(
            m.capture_time.as_deref(),
            Some(row["ExifIFD:DateTimeOriginal"].as_str()),
            "{name}"
        );
        assert_eq!(
            (m.width, m.height),
            (
                Some(num("ExifIFD:ExifImageWidth") as u32),
                Some(num("ExifIFD:ExifImageHeight") as u32)
            ),
            "{name}"
        );
        let exif = m.gps_exif.expect("EXIF GPS");
        let sign = |r: &str, neg: &str| if row[r] == neg { -1.0 } else { 1.0 };
        let lat = sign("GPS:GPSLatitudeRef", "S") * num("GPS:GPSLatitude");
        let lon = sign("GPS:GPSLongitudeRef", "W") * num("GPS:GPSLongitude");
        assert!(
            (exif.latitude_deg - lat).abs() < 1e-9 && (exif.longitude_deg - lon).abs() < 1e-9,
            "{name}: EXIF GPS {exif:?}, ExifTool {lat}, {lon}"
        );
        assert_eq!(exif.altitude_m, Some(num("GPS:GPSAltitude")), "{name}");
        let xmp = m.gps_xmp.expect("DJI XMP GPS");
        assert_eq!(xmp.latitude_deg, num("XMP-drone-dji:GPSLatitude"), "{name}");
        assert_eq!(
            xmp.longitude_deg,
            num("XMP-drone-dji:GPSLongitude"),
            "{name}"
        );
        assert_eq!(
            xmp.altitude_m,
            Some(num("XMP-drone-dji:AbsoluteAltitude")),
            "{name}"
        );
        assert_eq!(
            m.position(),
            Some(xmp),
            "{name}: the finer position is DJI's"
        );
        assert_eq!(
            m.relative_altitude_m,
            Some(num("XMP-drone-dji:RelativeAltitude")),
            "{name}"
        );
        let g = m.gimbal.expect("gimbal angles");
        let f = m.flight.expect("flight angles");
        for (ours, col) in [
            (g.yaw_deg, "GimbalYawDegree"),
            (g.pitch_deg, "GimbalPitchDegree"),
            (g.roll_deg, "GimbalRollDegree"),
            (f.yaw_deg, "FlightYawDegree"),
            (f.pitch_deg, "FlightPitchDegree"),
            (f.roll_deg, "FlightRollDegree"),
        ] {
            assert_eq!(ours, num(&format!("XMP-drone-dji:{col}")), "{name}: {col}");
        }
    }
}

#[test]
fn an_image_without_metadata_is_empty_and_damage_is_named() {
    let plain = ImageMeta::read(&shared_data("sun-board/thermal/Img05.jpg")).unwrap();
    assert_eq!(
        plain,
        ImageMeta::default(),
        "sun-board's thermal JPEGs carry no metadata"
    );

    let tmp = tempfile::tempdir().unwrap();
    // An APP1 Exif segment whose TIFF header is garbage.
    let mut bad_exif = vec![0xff, 0xd8, 0xff, 0xe1, 0x00, 0x10];
    bad_exif.extend_from_slice(b"Exif\0\0XXXXXXXX");
    bad_exif.extend_from_slice(&[0xff, 0xd9]);
    let path = tmp.path().join("bad_exif.jpg");
    std::fs::write(&path, &bad_exif).unwrap();
    let e = ImageMeta::read(&path).unwrap_err();
    let text = s3tir_capture::Chain(&e).to_string();
    assert!(
        matches!(e, MetaError::Damaged { part: "EXIF", .. }) && text.contains("bad_exif.jpg"),
        "{text}"
    );
    // An XMP packet that is not XML.
    let packet = b"http://ns.adobe.com/xap/1.0/\0<x:xmpmeta xmlns:x=\"adobe:ns:meta/\"><a></b>";
    let mut bad_xmp = vec![0xff, 0xd8, 0xff, 0xe1];
    bad_xmp.extend_from_slice(&((packet.len() + 2) as u16).to_be_bytes());
    bad_xmp.extend_from_slice(packet);
    bad_xmp.extend_from_slice(&[0xff, 0xd9]);
    let path = tmp.path().join("bad_xmp.jpg");
    std::fs::write(&path, &bad_xmp).unwrap();
    let e = ImageMeta::read(&path).unwrap_err();
    assert!(
        matches!(e, MetaError::Damaged { part: "XMP", .. }),
        "{}",
        s3tir_capture::Chain(&e)
    );
    // A missing file is named.
    let e = ImageMeta::read(&tmp.path().join("nope.jpg")).unwrap_err();
    assert!(s3tir_capture::Chain(&e).to_string().contains("nope.jpg"));
}
