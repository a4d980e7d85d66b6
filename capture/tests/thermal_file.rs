//! Proves the one reader of thermal image files: a FLIR frame is radiometric; 16-bit PNGs and
//! 16-bit and float TIFFs give kelvin in the unit the user states (and without a unit say how
//! to state one); 8-bit pictures (a real DJI thermal JPEG among them) are pictures, not
//! temperatures; colour or unknown files are named errors.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use s3tir_capture::radiometric::{ThermalFile, Units};

fn png16(path: &Path, w: u32, h: u32, words: &[u16], colour: png::ColorType) {
    let file = std::fs::File::create(path).unwrap();
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(colour);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut wr = enc.write_header().unwrap();
    let bytes: Vec<u8> = words.iter().flat_map(|x| x.to_be_bytes()).collect();
    wr.write_image_data(&bytes).unwrap();
}

fn kelvin(path: &Path, units: Units) -> Vec<f64> {
    let f = ThermalFile::read(path, Some(units)).unwrap();
    f.kelvin().expect("temperatures")
}

#[test]
fn sixteen_bit_and_float_images_read_in_the_stated_unit() {
    let tmp = tempfile::tempdir().unwrap();
    // 16-bit PNG in centikelvin: 293.15 K, 300.00 K, 0.01 K, 655.35 K
    let p = tmp.path().join("ck.png");
    png16(
        &p,
        2,
        2,
        &[29315, 30000, 1, 65535],
        png::ColorType::Grayscale,
    );
    let k = kelvin(&p, Units::CentiKelvin);
    for (a, b) in k.iter().zip([293.15, 300.0, 0.01, 655.35]) {
        assert!((a - b).abs() < 1e-9, "{k:?}");
    }
    // The same words without a unit: the error says how to state it.
    let e = s3tir_capture::Chain(&ThermalFile::read(&p, None).unwrap_err()).to_string();
    assert!(
        e.contains("ck.png") && e.contains("--units") && e.contains("centikelvin"),
        "{e}"
    );
    // Raw counts: no temperature.
    let raw = ThermalFile::read(&p, Some(Units::Raw)).unwrap();
    assert_eq!(raw.kelvin(), None, "raw counts are not temperatures");

    // 16-bit TIFF in millicelsius, float TIFF in celsius.
    let t = tmp.path().join("mc.tif");
    {
        let mut enc = tiff::encoder::TiffEncoder::new(std::fs::File::create(&t).unwrap()).unwrap();
        enc.write_image::<tiff::encoder::colortype::Gray16>(3, 1, &[0, 20000, 65535])
            .unwrap();
    }
    let k = kelvin(&t, Units::MilliCelsius);
    for (a, b) in k.iter().zip([273.15, 293.15, 338.685]) {
        assert!((a - b).abs() < 1e-9, "{k:?}");
    }
    let f = tmp.path().join("c.tif");
    {
        let mut enc = tiff::encoder::TiffEncoder::new(std::fs::File::create(&f).unwrap()).unwrap();
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(2, 1, &[-10.5, 36.6])
            .unwrap();
    }
    let k = kelvin(&f, Units::Celsius);
    assert!(
        (k[0] - 262.65).abs() < 1e-4 && (k[1] - 309.75).abs() < 1e-4,
        "{k:?}"
    );
    assert_eq!("CentiKelvin".parse::<Units>(), Ok(Units::CentiKelvin));
    let e = "fahrenheit".parse::<Units>().unwrap_err();
    assert!(
        e.contains("fahrenheit") && e.contains("millicelsius"),
        "{e}"
    );
}

#[test]
fn pictures_radiometric_files_and_bad_files_are_told_apart() {
    let tmp = tempfile::tempdir().unwrap();
    let flir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/flirpy/frame_000000.fff");
    let f = ThermalFile::read(&flir, None).unwrap();
    assert!(matches!(f, ThermalFile::Radiometric(_)));
    assert_eq!(f.size(), (640, 512));
    assert_eq!(f.kelvin().unwrap().len(), 640 * 512);

    let dji: PathBuf = std::env::var_os("S3TIR_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data/thermal-facade/images/DJI_0440.JPG");
    let f = ThermalFile::read(&dji, None).unwrap();
    assert_eq!(
        f,
        ThermalFile::Picture8 {
            width: 640,
            height: 480
        },
        "the Mavic 2 Enterprise Dual writes 8-bit pictures"
    );
    assert_eq!(f.kelvin(), None);

    let grey8 = tmp.path().join("g8.png");
    {
        let file = std::fs::File::create(&grey8).unwrap();
        let mut enc = png::Encoder::new(file, 3, 2);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .unwrap()
            .write_image_data(&[0; 6])
            .unwrap();
    }
    assert_eq!(
        ThermalFile::read(&grey8, Some(Units::Kelvin)).unwrap(),
        ThermalFile::Picture8 {
            width: 3,
            height: 2
        }
    );

    let rgb16 = tmp.path().join("rgb16.png");
    png16(&rgb16, 1, 1, &[1, 2, 3], png::ColorType::Rgb);
    let e = s3tir_capture::Chain(&ThermalFile::read(&rgb16, Some(Units::Kelvin)).unwrap_err())
        .to_string();
    assert!(
        e.contains("rgb16.png") && e.contains("one grey channel"),
        "{e}"
    );

    let junk = tmp.path().join("notes.txt");
    std::fs::write(&junk, "hello").unwrap();
    let e = s3tir_capture::Chain(&ThermalFile::read(&junk, None).unwrap_err()).to_string();
    assert!(
        e.contains("notes.txt") && e.contains("not a FLIR file, PNG, TIFF or JPEG"),
        "{e}"
    );
}
