//! Proves, through the `s3tir-train` binary, that `view RUN` is a viewer a person can use and a
//! server that gives away nothing else: it listens on the loopback by default, answers the
//! page, the vendored renderer, the scene description and the run folder's files, refuses
//! paths out of the run folder (plain, percent-encoded, symlinked), directories, other methods
//! and requests addressed to another host, and stops cleanly on Ctrl-C (SIGINT). In headless
//! Chromium, a run that had no mesh is meshed and shown with no console message, its colour
//! bar and ironbow surface on screen, and a click reads the temperature the mesh file holds at
//! that point (interpolated over the picked triangle, and the nearest vertex's own value).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod cli_run;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use cli_run::{bin, finished_run};
use s3tir_trainer::look::view::assets::{Vendored, default_dir};
use s3tir_trainer::mesh::extract::Mesh;
use s3tir_trainer::mesh::plyio::{read_mesh_ply, write_mesh_ply};

/// The vendored renderer is installed (scripts/install-viewer.py), or a visible skip (a
/// failure where `S3TIR_REQUIRE` names `viewer-assets`).
fn assets_installed() -> bool {
    match default_dir().map(|d| Vendored::load(&d)) {
        Some(Ok(_)) => true,
        Some(Err(e)) => {
            s3tir_capture::skip::skip("viewer-assets", &e.to_string());
            false
        }
        None => {
            s3tir_capture::skip::skip("viewer-assets", "no data folder (HOME unset)");
            false
        }
    }
}

/// A running `s3tir-train view RUN --port 0`; killed if a test fails before stopping it.
struct Viewer {
    child: Option<Child>,
    url: String,
}

impl Viewer {
    /// Starts the viewer and waits for its URL line (after meshing, when the run has no mesh).
    fn start(run: &Path) -> Self {
        let mut child = bin()
            .arg("view")
            .arg(run)
            .args(["--port", "0"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Meshing's summary may come first; the URL is the line `viewer: URL`.
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut printed = String::new();
        let url = loop {
            let mut line = String::new();
            if stdout.read_line(&mut line).unwrap() == 0 {
                break None;
            }
            printed.push_str(&line);
            if let Some(url) = line.trim().strip_prefix("viewer: ") {
                break Some(url.to_owned());
            }
        };
        let mut v = Self {
            child: Some(child),
            url: String::new(),
        };
        let Some(url) = url else {
            let err = v.stop_output();
            panic!("the viewer printed {printed:?}, expected `viewer: URL`; stderr: {err}");
        };
        v.url = url;
        v
    }

    /// host:port of the URL.
    fn authority(&self) -> &str {
        self.url.trim_start_matches("http://").trim_end_matches('/')
    }

    /// Sends SIGINT (Ctrl-C) and waits for the exit; returns stderr. Panics unless it exits
    /// with success within 10 s.
    fn stop(&mut self) -> String {
        let mut child = self.child.take().unwrap();
        let st = std::process::Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status()
            .unwrap();
        assert!(st.success(), "kill -INT failed");
        let t0 = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if t0.elapsed() > Duration::from_secs(10) {
                child.kill().ok();
                panic!("the viewer did not stop within 10 s of Ctrl-C");
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let mut err = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        assert!(
            status.success(),
            "the viewer exited {status} on Ctrl-C: {err}"
        );
        err
    }

    /// Kills it and returns its stderr (for a failure message).
    fn stop_output(&mut self) -> String {
        let Some(mut child) = self.child.take() else {
            return String::new();
        };
        child.kill().ok();
        let mut err = String::new();
        if let Some(mut e) = child.stderr.take() {
            e.read_to_string(&mut err).ok();
        }
        child.wait().ok();
        err
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        self.stop_output();
    }
}

/// Sends `request` (the request line and headers, without the final blank line) as written —
/// no client normalises the path — and returns the status code and body.
fn raw(authority: &str, request: &str) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(authority).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "{request}\r\nConnection: close\r\n\r\n").unwrap();
    let mut bytes = Vec::new();
    s.read_to_end(&mut bytes).unwrap();
    let end = bytes
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a complete response head");
    let head = String::from_utf8_lossy(&bytes[..end]).into_owned();
    let code = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or_else(|| panic!("no status in {head:?}"));
    (code, bytes[end + 4..].to_vec())
}

fn get(authority: &str, path: &str) -> (u16, Vec<u8>) {
    raw(
        authority,
        &format!("GET {path} HTTP/1.1\r\nHost: {authority}"),
    )
}

/// A run folder holding a two-triangle mesh, a render and a symlink to a file outside it.
fn small_run(dir: &Path) -> std::path::PathBuf {
    let run = dir.join("run");
    std::fs::create_dir_all(run.join("renders")).unwrap();
    std::fs::write(run.join("config.json"), "{}").unwrap();
    std::fs::write(run.join("renders/thermal_0.png"), b"png").unwrap();
    std::fs::write(dir.join("secret.txt"), b"SECRET-OUTSIDE-THE-RUN").unwrap();
    std::os::unix::fs::symlink(dir.join("secret.txt"), run.join("link.txt")).unwrap();
    let mesh = Mesh {
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        kelvin: vec![290.0, 300.0, 310.0, f32::NAN],
        rgb: None,
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    };
    write_mesh_ply(&run.join("mesh.ply"), &mesh, None, "test mesh").unwrap();
    run
}

#[test]
fn the_viewer_serves_the_run_folder_only_and_stops_on_ctrl_c() {
    if !assets_installed() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let run = small_run(tmp.path());
    let mut v = Viewer::start(&run);
    assert!(
        v.url.starts_with("http://127.0.0.1:"),
        "the viewer listens on the loopback by default, not {}",
        v.url
    );
    let a = v.authority().to_owned();

    let (code, page) = get(&a, "/");
    assert_eq!(code, 200, "the page");
    assert!(String::from_utf8_lossy(&page).contains("<canvas id=\"view\""));
    let (code, js) = get(&a, "/vendor/three.module.js");
    assert_eq!(code, 200, "the vendored renderer");
    assert!(js.len() > 100_000, "three.module.js is {} bytes", js.len());
    let (code, scene) = get(&a, "/api/scene.json");
    assert_eq!(code, 200, "the scene description");
    let scene: serde_json::Value = serde_json::from_slice(&scene).unwrap();
    assert_eq!(scene["meshes"][0]["name"], "mesh.ply", "{scene}");
    assert_eq!(scene["meshes"][0]["unobserved"], 1, "{scene}");
    assert!(
        scene["radiometric"].is_null(),
        "without a loadable dataset the unit is unknown, not guessed: {}",
        scene["radiometric"]
    );
    let (code, ply) = get(&a, "/run/mesh.ply");
    assert_eq!(code, 200, "a file of the run folder");
    assert_eq!(ply, std::fs::read(run.join("mesh.ply")).unwrap());

    for path in [
        "/run/../secret.txt",
        "/run/%2e%2e/secret.txt",
        "/run/..%2fsecret.txt",
        "/run/renders/../../secret.txt",
        "/run//etc/passwd",
        "/run/link.txt",
        "/run/renders",
        "/run/renders/",
        "/run/",
        "/vendor/../config.json",
        "/config.json",
        "/../secret.txt",
    ] {
        let (code, body) = get(&a, path);
        assert_eq!(code, 404, "{path} must be refused");
        assert!(
            !String::from_utf8_lossy(&body).contains("SECRET") && !body.starts_with(b"ply"),
            "{path} leaked a file"
        );
    }
    let (code, _) = raw(
        &a,
        &format!("POST /api/scene.json HTTP/1.1\r\nHost: {a}\r\nContent-Length: 0"),
    );
    assert_eq!(code, 405, "only GET and HEAD");
    let (code, _) = raw(
        &a,
        "GET /run/mesh.ply HTTP/1.1\r\nHost: attacker.example:8765",
    );
    assert_eq!(
        code, 403,
        "a request addressed to another host (DNS rebinding)"
    );
    let (code, _) = raw(&a, "GET /run/mesh.ply HTTP/1.1\r\nHost: localhost:8765");
    assert_eq!(code, 200, "localhost is the loopback");

    let err = v.stop();
    assert!(
        err.contains("viewer stopped"),
        "the viewer says it stopped: {err}"
    );
}

/// Where `p` lies in triangle (a, b, c): barycentric weights (least squares in its plane) and
/// the distance from the plane.
fn barycentric(p: [f64; 3], t: [[f64; 3]; 3]) -> ([f64; 3], f64) {
    let sub = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let (e0, e1, d) = (sub(t[1], t[0]), sub(t[2], t[0]), sub(p, t[0]));
    let (a, b, c) = (dot(e0, e0), dot(e0, e1), dot(e1, e1));
    let (r0, r1) = (dot(d, e0), dot(d, e1));
    let det = a * c - b * b;
    let v = (c * r0 - b * r1) / det;
    let w = (a * r1 - b * r0) / det;
    let on = [
        t[0][0] + v * e0[0] + w * e1[0],
        t[0][1] + v * e0[1] + w * e1[1],
        t[0][2] + v * e0[2] + w * e1[2],
    ];
    let off = sub(p, on);
    ([1.0 - v - w, v, w], dot(off, off).sqrt())
}

/// The value of attribute `name` of the `<output id="pick">` element in a dumped DOM.
fn pick_attr<'a>(dom: &'a str, name: &str) -> &'a str {
    let start = dom
        .find("<output id=\"pick\"")
        .unwrap_or_else(|| panic!("no pick output in the page:\n{dom}"));
    let tag = &dom[start..start + dom[start..].find('>').unwrap()];
    let key = format!("{name}=\"");
    let i = tag
        .find(&key)
        .unwrap_or_else(|| panic!("the pick output has no {name}: {tag}"))
        + key.len();
    &tag[i..i + tag[i..].find('"').unwrap()]
}

#[test]
fn the_viewer_shows_the_mesh_in_chromium_and_reads_its_temperatures() {
    if !assets_installed() {
        return;
    }
    let Some(chromium) = cli_run::chromium() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (_, run, _) = finished_run(tmp.path());
    assert!(!run.join("mesh.ply").exists(), "training writes no mesh");
    let mut v = Viewer::start(&run);
    // A click where the page shows the centroid of the triangle nearest the first held-out
    // view's axis (the page starts at that view; a short run's mesh has holes, so the canvas's
    // centre may show none). Whatever triangle the click lands on is checked against the file.
    let (_, scene) = get(v.authority(), "/api/scene.json");
    let scene: serde_json::Value = serde_json::from_slice(&scene).unwrap();
    let vec3 = |k: &str| -> [f64; 3] {
        let a = scene["camera"][k]
            .as_array()
            .unwrap_or_else(|| panic!("camera.{k}: {scene}"));
        [0, 1, 2].map(|i| a[i].as_f64().unwrap())
    };
    let (eye, fwd) = (vec3("eye"), vec3("forward"));
    let mesh = read_mesh_ply(&run.join("mesh.ply")).unwrap();
    let angle = |c: [f64; 3]| {
        let d = [c[0] - eye[0], c[1] - eye[1], c[2] - eye[2]];
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        -(d[0] * fwd[0] + d[1] * fwd[1] + d[2] * fwd[2]) / n
    };
    let target = mesh
        .triangles
        .iter()
        .map(|t| {
            let c = corners(&mesh, t);
            [0, 1, 2].map(|k| (c[0][k] + c[1][k] + c[2][k]) / 3.0)
        })
        .min_by(|a, b| angle(*a).total_cmp(&angle(*b)))
        .expect("the mesh has triangles");
    let url = format!("{}?pickat={},{},{}", v.url, target[0], target[1], target[2]);
    let profile = tmp.path().join("profile");
    let dom = cli_run::headless(chromium, &profile, "900,700")
        .args(["--virtual-time-budget=30000", "--dump-dom", &url])
        .output()
        .unwrap();
    let dom_text = String::from_utf8_lossy(&dom.stdout).into_owned();
    assert!(
        dom_text.contains("data-ready=\"1\""),
        "the page did not finish loading: {}\n{}",
        dom_text,
        String::from_utf8_lossy(&dom.stderr)
    );
    let console = cli_run::console_messages(&dom.stderr);
    assert!(
        console.is_empty(),
        "the page logs to the console: {console:?}"
    );

    assert_eq!(
        pick_attr(&dom_text, "data-hit"),
        "1",
        "a click on a triangle's centroid ({target:?}) hits the surface"
    );
    let face: usize = pick_attr(&dom_text, "data-face").parse().unwrap();
    let ids: Vec<u32> = pick_attr(&dom_text, "data-vertices")
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect();
    let mut tri = mesh.triangles[face].to_vec();
    let mut shown = ids.clone();
    tri.sort_unstable();
    shown.sort_unstable();
    assert_eq!(
        shown, tri,
        "the picked triangle is triangle {face} of the file"
    );
    let nearest: usize = pick_attr(&dom_text, "data-nearest").parse().unwrap();
    let nearest_value: f64 = pick_attr(&dom_text, "data-nearest-value").parse().unwrap();
    assert!(
        (nearest_value - f64::from(mesh.kelvin[nearest])).abs() < 0.1,
        "vertex {nearest}: the page shows {nearest_value} K, the file holds {} K",
        mesh.kelvin[nearest]
    );
    let point: Vec<f64> = pick_attr(&dom_text, "data-point")
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect();
    let corners = corners(&mesh, &ids);
    let (w, off) = barycentric([point[0], point[1], point[2]], corners);
    let edge = (0..3)
        .map(|k| (corners[0][k] - corners[1][k]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(
        off < 1e-3 * edge.max(1e-6) && w.iter().all(|&x| x > -1e-3),
        "the picked point {point:?} lies on its triangle (off by {off}, weights {w:?})"
    );
    let expected: f64 = ids
        .iter()
        .zip(w)
        .map(|(&i, w)| w * f64::from(mesh.kelvin[i as usize]))
        .sum();
    let value: f64 = pick_attr(&dom_text, "data-value").parse().unwrap();
    assert!(
        (value - expected).abs() < 0.1,
        "the page reads {value} K at the picked point, the file's vertices give {expected} K"
    );
    assert!(
        (250.0..400.0).contains(&value),
        "a radiometric run's value is in kelvin: {value}"
    );

    // As a person sees it: the surface and the colour bar in ironbow, nothing blank.
    let shot = tmp.path().join("viewer.png");
    let (console, img) = cli_run::screenshot(
        chromium,
        &profile,
        "900,700",
        &["--virtual-time-budget=30000"],
        &v.url,
        &shot,
    );
    assert!(
        console.is_empty(),
        "the page logs to the console: {console:?}"
    );
    // The surface alone (the colour bar's 150 px at the right left out), then the bar.
    let (w, h) = img.dimensions();
    let surface = image::imageops::crop_imm(&img, 0, 0, w - 170, h).to_image();
    let on_surface = cli_run::ironbow_pixels(&surface);
    assert!(
        on_surface > 5000,
        "the screenshot shows the surface in ironbow: {on_surface} pixels left of the bar"
    );
    let bar = image::imageops::crop_imm(&img, w - 170, 0, 170, h).to_image();
    let on_bar = cli_run::ironbow_pixels(&bar);
    assert!(on_bar > 2000, "the colour bar in ironbow: {on_bar} pixels");
    let err = v.stop();
    assert!(
        err.contains("has no mesh: meshing it first"),
        "the viewer says it meshed the run: {err}"
    );
}

/// The corners of the triangle with vertex indices `ids`.
fn corners(mesh: &Mesh, ids: &[u32]) -> [[f64; 3]; 3] {
    assert!(ids.len() == 3, "a triangle has three corners");
    let p = |k: usize| mesh.positions[ids[k] as usize].map(f64::from);
    [p(0), p(1), p(2)]
}
