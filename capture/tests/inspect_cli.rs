//! Proves `s3tir-capture inspect` as a user runs it: the Duo Pro R frame's summary (camera,
//! calibration, temperatures), its 16-bit centikelvin PNG read back equal to the decoder's
//! kelvin within half a count, inspect.json naming the conditions used (an override shows
//! there and moves the temperatures the right way), a real DJI thermal JPEG's metadata and
//! the absence of temperatures said, and a bad file or condition named.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::Command;

use s3tir_capture::radiometric::Radiometric;

fn frame() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/flirpy/frame_000000.fff")
}

fn capture() -> Command {
    Command::new(env!("CARGO_BIN_EXE_s3tir-capture"))
}

#[test]
fn a_frame_is_summarised_and_written_as_centikelvin() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = capture()
        .arg("inspect")
        .arg(frame())
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "radiometric failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        text.contains("Duo Pro R")
            && text.contains("640×512")
            && text.contains("364058")
            && text.contains("53.4489064°, -2.8150262°, 81.02 m (FLIR GPS record)"),
        "the summary names the camera, size and calibration: {text}"
    );
    // The PNG holds the decoder's kelvin at 0.01 K per count.
    let r = Radiometric::read(&frame()).unwrap();
    let kelvin = r.kelvin(&r.camera.conditions);
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(out.join("frame_000000.png")).unwrap(),
    ));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut buf).unwrap();
    let words: Vec<u16> = buf
        .chunks_exact(2)
        .map(|w| u16::from_be_bytes([w[0], w[1]]))
        .collect();
    assert_eq!(words.len(), 640 * 512);
    let worst = words
        .iter()
        .zip(&kelvin)
        .map(|(&w, &k)| (f64::from(w) / 100.0 - k).abs())
        .fold(0.0, f64::max);
    assert!(worst <= 0.005 + 1e-9, "PNG vs decoder: {worst} K");

    // An override is used, recorded, and moves the temperatures the right way: with a lower
    // emissivity more of the words are reflection, so the object is farther from the reflected
    // temperature (20 °C; this scene is colder than that).
    let o = capture()
        .arg("inspect")
        .arg(frame())
        .args(["--emissivity", "0.80", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let used = v[0]["radiometric"]["conditions_used"]["emissivity"]
        .as_f64()
        .unwrap();
    assert!((used - 0.8).abs() < 1e-12, "conditions_used: {used}");
    let median: f64 = v[0]["radiometric"]["kelvin_median"].as_f64().unwrap();
    let mut own: Vec<f64> = kelvin.clone();
    own.sort_by(f64::total_cmp);
    let reflected = r.camera.conditions.reflected_k;
    assert!(
        (median - reflected).abs() > (own[own.len() / 2] - reflected).abs() + 0.5,
        "emissivity 0.80 reads farther from the reflected {reflected} K than 0.94: {median} vs {}",
        own[own.len() / 2]
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("inspect.json")).unwrap()).unwrap();
    assert!(
        (json[0]["radiometric"]["conditions_used"]["emissivity"]
            .as_f64()
            .unwrap()
            - 0.94)
            .abs()
            < 1e-3,
        "inspect.json records the file's emissivity for the first run"
    );

    // Bad input: a condition out of range, a file that is not radiometric.
    let o = capture()
        .arg("inspect")
        .arg(frame())
        .args(["--emissivity", "1.5"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("emissivity 1.5"),
        "{err}"
    );
    let plain = tmp.path().join("photo.jpg");
    std::fs::write(&plain, b"\xff\xd8\xff\xe0\x00\x04ab\xff\x00\xff\xd9").unwrap();
    let o = capture().arg("inspect").arg(&plain).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("photo.jpg"),
        "a damaged JPEG is named: {err}"
    );

    // A real DJI thermal JPEG: its position and gimbal, and no temperatures (8-bit).
    let dji = std::env::var_os("S3TIR_SHARED_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data/thermal-facade/images/DJI_0440.JPG");
    let o = capture().arg("inspect").arg(&dji).output().unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success()
            && text.contains("DJI FC2403")
            && text.contains("-36.8740753")
            && text.contains("gimbal yaw 113.20")
            && text.contains("640×480 8-bit picture: no temperatures"),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );

    // A 16-bit PNG in a stated unit: its temperatures, and written in centikelvin.
    let mc = tmp.path().join("mc.png");
    {
        let file = std::fs::File::create(&mc).unwrap();
        let mut enc = png::Encoder::new(file, 2, 1);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let words: [u16; 2] = [20000, 36600]; // millicelsius: 20.0 °C, 36.6 °C
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
        enc.write_header()
            .unwrap()
            .write_image_data(&bytes)
            .unwrap();
    }
    let o = capture().arg("inspect").arg(&mc).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--units"),
        "a unit is asked for: {err}"
    );
    let o = capture()
        .arg("inspect")
        .arg(&mc)
        .args(["--units", "millicelsius", "--json", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let hi = v[0]["scaled"]["kelvin_max"].as_f64().unwrap();
    assert!((hi - 309.75).abs() < 1e-9, "36.6 °C is 309.75 K: {hi}");
    let written = std::fs::read(out.join("mc.png")).unwrap();
    let mut reader = png::Decoder::new(std::io::Cursor::new(written))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut buf).unwrap();
    assert_eq!(
        buf,
        [29315u16, 30975]
            .iter()
            .flat_map(|w| w.to_be_bytes())
            .collect::<Vec<u8>>(),
        "written in centikelvin"
    );

    // --out never overwrites an input, nor writes two inputs to one name.
    let o = capture()
        .arg("inspect")
        .arg(&mc)
        .args(["--units", "millicelsius", "--out"])
        .arg(tmp.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("overwrite the input"),
        "{err}"
    );
    let other = tmp.path().join("sub");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::copy(&mc, other.join("mc.png")).unwrap();
    let o = capture()
        .arg("inspect")
        .arg(&mc)
        .arg(other.join("mc.png"))
        .args(["--units", "millicelsius", "--out"])
        .arg(tmp.path().join("third"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("would both be written"),
        "{err}"
    );
}
