//! Proves, through the `s3tir-train` binary, that a finished run has a report a person can
//! read: `report.html` self-contained (every image a `data:` URI, no URL outside the page),
//! one recorded | rendered | error figure per held-out view, the readable ironbow copy beside
//! each 16-bit render with its kelvin range in the file, the summary naming the page;
//! `report RUN` writes it again, and with the dataset gone it still writes the page and says
//! what it could not show; headless Chromium opens the page with no console message and shows
//! its colour bars; `render --path views` reproduces the held-out renders, an orbit writes
//! its frames and video. Does NOT judge how the figures look (look::figure's unit tests check
//! their pixels).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod cli_run;

use std::path::Path;

use cli_run::{bin, finished_run};

use s3tir_trainer::look::image::read_scale;

/// `s3tir-train report RUN`, which must succeed.
fn report_again(run: &Path) -> std::process::Output {
    let out = bin().arg("report").arg(run).output().unwrap();
    assert!(
        out.status.success(),
        "report {}: {}",
        run.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `s3tir-train render RUN ARGS --out OUT`, run to its end.
fn render(run: &Path, out: &Path, args: &[&str]) -> std::process::Output {
    bin()
        .arg("render")
        .arg(run)
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

/// The held-out views' file stems, from eval.json.
fn held_out_stems(run: &Path) -> Vec<String> {
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval.json")).unwrap()).unwrap();
    eval["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| {
            Path::new(v["name"].as_str().unwrap())
                .file_stem()
                .unwrap()
                .to_string_lossy()
                .into_owned()
        })
        .collect()
}

/// Every `src="…"` and `href="…"` of the page: images embedded, links only to files beside it.
fn assert_self_contained(html: &str) {
    for attr in ["src=\"", "href=\""] {
        for part in html.split(attr).skip(1) {
            let value = part.split('"').next().unwrap();
            let local = if attr == "src=\"" {
                value.starts_with("data:image/png;base64,")
            } else {
                !value.contains("://") && !value.starts_with('/')
            };
            assert!(local, "{attr}{value:.60}… leaves the page");
        }
    }
    assert!(
        !html.contains("http://") && !html.contains("https://"),
        "no URL in the page"
    );
}

#[test]
fn a_finished_run_has_a_self_contained_report_with_every_held_out_view() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, run, stdout) = finished_run(tmp.path());
    let html_path = run.join("report.html");
    assert!(
        stdout.contains("report: ") && stdout.contains("report.html"),
        "the summary names the report: {stdout}"
    );
    let html = std::fs::read_to_string(&html_path).unwrap();
    assert_self_contained(&html);
    let stems = held_out_stems(&run);
    assert_eq!(stems.len(), 2, "the scene holds 2 views out");
    for stem in &stems {
        let fig = run.join("report").join(format!("view_{stem}.png"));
        let img = image::open(&fig).unwrap();
        assert!(
            img.width() > 3 * 24 && img.height() > 18,
            "{}: three panels and their bars ({}×{})",
            fig.display(),
            img.width(),
            img.height()
        );
        assert!(html.contains(stem.as_str()), "the page shows view {stem}");
        let copy = run.join("renders").join(format!("{stem}_ironbow.png"));
        let scale = read_scale(&copy).unwrap();
        assert_eq!(scale.unit, "K", "radiometric renders are drawn in kelvin");
        assert!(
            scale.lo > 200.0 && scale.hi < 400.0 && scale.hi > scale.lo,
            "the copy's range is the recorded frame's, in kelvin: {scale:?}"
        );
    }
    for section in [
        "Held-out figures",
        "Held-out views",
        "G-buffers",
        "Density control",
    ] {
        assert!(html.contains(section), "the page has the {section} section");
    }
    assert!(
        html.contains("kelvin and °C"),
        "radiometric: bars in K and °C"
    );
    assert!(run.join("report.md").is_file(), "the Markdown twin");

    // Written again by `report`.
    std::fs::remove_file(&html_path).unwrap();
    let out = report_again(&run);
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("report.html") && html_path.is_file(),
        "`report RUN` writes the page again and prints its path"
    );

    // Without the dataset: the page still comes, saying what it cannot show.
    std::fs::rename(&data, tmp.path().join("moved")).unwrap();
    let out = report_again(&run);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("recorded frames not shown") && err.contains("scene"),
        "stderr names the missing dataset: {err}"
    );
    let html = std::fs::read_to_string(&html_path).unwrap();
    assert!(
        html.contains("recorded frames not shown"),
        "the page says what it cannot show"
    );
    assert_self_contained(&html);
}

#[test]
fn report_of_a_folder_that_is_not_a_run_names_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let out = bin()
        .args(["report", tmp.path().to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success(), "no run, no report");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("config.json"),
        "the error names the missing file: {err}"
    );
}

/// The page as a user's browser shows it: headless Chromium (Debian's `chromium`, installed by
/// scripts/install-deps.sh) loads it without a console message, and its screenshot is not blank
/// and holds the ironbow panels and colour bars.
#[test]
fn the_report_opens_in_headless_chromium_with_its_colour_bars() {
    let Some(chromium) = cli_run::chromium() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (_, run, _) = finished_run(tmp.path());
    let shot = tmp.path().join("shot.png");
    let page = run.join("report.html").canonicalize().unwrap();
    let (console, img) = cli_run::screenshot(
        chromium,
        &tmp.path().join("profile"),
        "1000,2600",
        &[],
        &format!("file://{}", page.display()),
        &shot,
    );
    assert!(
        console.is_empty(),
        "the page logs to the console: {console:?}"
    );
    let n = (img.width() * img.height()) as usize;
    let inked = cli_run::inked_pixels(&img);
    assert!(
        inked * 50 > n,
        "the screenshot is nearly blank: {inked} of {n} pixels inked"
    );
    // Ironbow's saturated entries (the grey ends excluded): the panels and bars in the palette.
    let ironbow = cli_run::ironbow_pixels(&img);
    assert!(
        ironbow > 2000,
        "the screenshot shows ironbow panels and bars: {ironbow} pixels in the palette"
    );
}

/// `render --path views` passes through the held-out poses: each frame's panel is the view's
/// 16-bit render drawn through the frame's own scale (read back from the frame), pixel for
/// pixel within one palette step; an orbit writes its frames and a video; a bad path file is
/// named.
#[test]
fn render_along_the_held_out_views_reproduces_their_renders() {
    use s3tir_calib::model::palette::Colormap;
    use s3tir_trainer::look::figure::{Panel, panel_origin_and_up};
    use s3tir_trainer::look::image::Scale;

    let tmp = tempfile::tempdir().unwrap();
    let (_, run, _) = finished_run(tmp.path());
    let out = tmp.path().join("views");
    let o = render(&run, &out, &["--path", "views", "--no-video", "--json"]);
    assert!(
        o.status.success(),
        "render: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let frames: Vec<String> = v["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap().to_owned())
        .collect();
    let stems = held_out_stems(&run);
    assert_eq!(frames.len(), stems.len(), "one frame per held-out view");
    let probe = Panel {
        title: String::new(),
        plane: vec![0.0; 24 * 18],
        width: 24,
        height: 18,
        scale: Scale::new(Colormap::Ironbow, 0.0, 1.0, "K"),
    };
    let ((x0, y0), up) = panel_origin_and_up(&probe);
    assert!(up >= 1, "a 24 px view is shown enlarged");
    for (frame, stem) in frames.iter().zip(&stems) {
        let scale = read_scale(Path::new(frame)).unwrap();
        assert_eq!(scale.unit, "K");
        let img = image::open(frame).unwrap().to_rgb8();
        let render = image::open(run.join("renders").join(format!("{stem}.png")))
            .unwrap()
            .into_luma16();
        let mut worst = 0i32;
        for (x, y, word) in render.enumerate_pixels() {
            // Radiometric renders are centikelvin.
            let want = (scale.position(f64::from(word.0[0]) / 100.0) * 255.0).round() as i32;
            let p = img.get_pixel(x0 + up * x + up / 2, y0 + up * y + up / 2).0;
            let got = scale.palette.nearest(p).0 as i32;
            worst = worst.max((got - want).abs());
        }
        assert!(
            worst <= 1,
            "{frame}: the frame differs from renders/{stem}.png by {worst} palette steps"
        );
    }

    // An orbit: frames and a video, as an animated GIF (always) and as MP4 through ffmpeg.
    let orbit = |format: &str| {
        let o = render(
            &run,
            &tmp.path().join(format!("orbit-{format}")),
            &[
                "--path", "orbit", "--frames", "6", "--video", format, "--json",
            ],
        );
        assert!(
            o.status.success(),
            "orbit, {format}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["frames"].as_array().unwrap().len(), 6);
        let video = Path::new(v["video"].as_str().expect("a video")).to_path_buf();
        assert!(
            video.extension().is_some_and(|e| e == format)
                && std::fs::metadata(&video).unwrap().len() > 1000,
            "{} is written as {format} ({})",
            video.display(),
            v["video_how"]
        );
        video
    };
    let gif = orbit("gif");
    let frames = ::image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
        std::fs::File::open(&gif).unwrap(),
    ))
    .map(|d| ::image::AnimationDecoder::into_frames(d).count())
    .unwrap();
    assert_eq!(frames, 6, "{} holds the orbit's 6 frames", gif.display());
    if std::process::Command::new("ffprobe")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success())
    {
        let mp4 = orbit("mp4");
        let probe = std::process::Command::new("ffprobe")
            .args(["-v", "error", "-count_frames", "-select_streams", "v:0"])
            .args([
                "-show_entries",
                "stream=codec_name,nb_read_frames",
                "-of",
                "csv=p=0",
            ])
            .arg(&mp4)
            .output()
            .unwrap();
        let probe = String::from_utf8_lossy(&probe.stdout).trim().to_string();
        assert_eq!(probe, "h264,6", "{} is H.264 with 6 frames", mp4.display());
    } else {
        s3tir_capture::skip::skip(
            "ffmpeg",
            "no ffmpeg/ffprobe on PATH: the MP4 branch is not run",
        );
    }
    // Asked for MP4 where no ffmpeg runs: an error that says so, not a GIF in its place.
    let o = bin()
        .arg("render")
        .arg(&run)
        .args([
            "--path", "orbit", "--frames", "2", "--video", "mp4", "--out",
        ])
        .arg(tmp.path().join("orbit-no-ffmpeg"))
        .env("PATH", tmp.path().join("no-bin"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("flight.mp4") && err.contains("--video gif"),
        "--video mp4 without ffmpeg fails naming the file and the way out: {err}"
    );

    // A path file that is not one is named with the expected layout.
    let bad = tmp.path().join("path.json");
    std::fs::write(&bad, "{\"frames\": 3}").unwrap();
    let o = render(
        &run,
        &tmp.path().join("bad"),
        &["--path", bad.to_str().unwrap()],
    );
    assert!(!o.status.success(), "a bad path file fails");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("path.json") && err.contains("\"eye\""),
        "the error names the file and the layout: {err}"
    );
}
