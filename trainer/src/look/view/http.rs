//! The viewer's HTTP server: the page, the vendored renderer, the scene description and the run
//! folder's files — nothing else.
//!
//! | path | what |
//! |---|---|
//! | `/`, `/index.html`, `/viewer.js` | the page (inside the binary) |
//! | `/vendor/NAME` | a vendored three.js file ([`super::assets::VENDORED`]) |
//! | `/api/scene.json` | [`super::scene::SceneInfo`] |
//! | `/run/REL` | the file `REL` of the run folder |
//!
//! `REL` is percent-decoded, then refused if a segment is empty, `.` or `..` or holds a
//! backslash or NUL; the joined path is canonicalised (symlinks resolved) and must be a file
//! inside the canonical run folder. Directories are never listed. Only GET and HEAD are
//! answered. A request whose `Host` is a name other than `localhost` or the names the user
//! allowed (`--allow-host`) is refused, whatever address the server listens on: a web page
//! elsewhere cannot reach the viewer through DNS rebinding (which needs a name; an IP address
//! in `Host` is what a browser sends when the user typed one).

use std::fs::File;
use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use percent_encoding::percent_decode_str;
use tiny_http::{Header, Method, Request, Response, StatusCode};

use super::ViewError;
use super::assets::{INDEX_HTML, VIEWER_JS, Vendored};

/// How often the serving loop looks at the stop flag.
const POLL: Duration = Duration::from_millis(100);

/// A bound viewer server; [`ViewServer::serve_until`] answers requests.
pub struct ViewServer {
    inner: tiny_http::Server,
    addr: SocketAddr,
    /// The canonical run folder.
    root: PathBuf,
    vendored: Vendored,
    scene_json: Vec<u8>,
    /// Host names accepted besides `localhost` and IP addresses (lower case).
    allowed_hosts: Vec<String>,
}

impl std::fmt::Debug for ViewServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ViewServer")
            .field("addr", &self.addr)
            .field("root", &self.root)
            .finish_non_exhaustive()
    }
}

/// What a serving loop answered.
#[derive(Debug, Clone, Copy, Default)]
pub struct ServeStats {
    pub requests: usize,
    /// Answered 4xx/5xx.
    pub refused: usize,
}

impl ViewServer {
    /// Listens on `addr` (port 0: a free port) for the run folder `run_dir`; `scene_json` is
    /// what `/api/scene.json` answers; `allowed_hosts`: host names accepted in `Host` besides
    /// `localhost` and IP addresses (e.g. the rig's name when listening beyond the loopback).
    pub fn bind(
        run_dir: &Path,
        addr: SocketAddr,
        vendored: Vendored,
        scene_json: Vec<u8>,
        allowed_hosts: &[String],
    ) -> Result<Self, ViewError> {
        let root = run_dir.canonicalize().map_err(|source| ViewError::Io {
            path: run_dir.to_path_buf(),
            source,
        })?;
        let inner = tiny_http::Server::http(addr).map_err(|e| ViewError::Listen {
            addr: addr.to_string(),
            reason: e.to_string(),
        })?;
        let addr = inner
            .server_addr()
            .to_ip()
            .ok_or_else(|| ViewError::Listen {
                addr: addr.to_string(),
                reason: "the server has no IP address".into(),
            })?;
        Ok(Self {
            inner,
            addr,
            root,
            vendored,
            scene_json,
            allowed_hosts: allowed_hosts
                .iter()
                .map(|h| h.to_ascii_lowercase())
                .collect(),
        })
    }

    /// The address it listens on (the port chosen when 0 was asked).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's URL.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// Answers requests until `stop` is set (checked every 100 ms).
    pub fn serve_until(&self, stop: &AtomicBool) -> Result<ServeStats, ViewError> {
        let mut stats = ServeStats::default();
        while !stop.load(Ordering::SeqCst) {
            let request = match self.inner.recv_timeout(POLL) {
                Ok(Some(r)) => r,
                Ok(None) => continue,
                Err(source) => {
                    return Err(ViewError::Io {
                        path: PathBuf::from(self.url()),
                        source,
                    });
                }
            };
            stats.requests += 1;
            if !self.answer(request) {
                stats.refused += 1;
            }
        }
        Ok(stats)
    }

    /// Answers one request; false when it was refused (4xx/5xx).
    fn answer(&self, request: Request) -> bool {
        let method = request.method().clone();
        let url = request.url().to_string();
        let reply = if !matches!(method, Method::Get | Method::Head) {
            Reply::Status(405, "GET and HEAD only")
        } else if !host_allowed(&request, &self.allowed_hosts) {
            Reply::Status(
                403,
                "the viewer answers requests addressed to an IP address, localhost or a name \
                 given with --allow-host",
            )
        } else {
            self.route(&url)
        };
        let status = reply.status();
        tracing::debug!(%method, %url, status, "viewer request");
        let sent = match reply {
            Reply::Bytes(body, kind) => request.respond(with_type(Response::from_data(body), kind)),
            Reply::Static(body, kind) => {
                request.respond(with_type(Response::from_data(body.as_bytes()), kind))
            }
            Reply::File(file, kind) => request.respond(with_type(Response::from_file(file), kind)),
            Reply::Status(code, why) => request.respond(
                with_type(Response::from_string(why), "text/plain; charset=utf-8")
                    .with_status_code(StatusCode(code)),
            ),
        };
        if let Err(e) = sent {
            tracing::debug!(%url, error = %e, "viewer: the client went away");
        }
        status < 400
    }

    fn route(&self, url: &str) -> Reply {
        let path = url.split(['?', '#']).next().unwrap_or("");
        match path {
            "/" | "/index.html" => Reply::Static(INDEX_HTML, "text/html; charset=utf-8"),
            "/viewer.js" => Reply::Static(VIEWER_JS, "text/javascript; charset=utf-8"),
            "/api/scene.json" => Reply::Bytes(self.scene_json.clone(), "application/json"),
            _ => {
                if let Some(name) = path.strip_prefix("/vendor/") {
                    return match self.vendored.get(name) {
                        Some(b) => Reply::Bytes(b.to_vec(), content_type(Path::new(name))),
                        None => Reply::Status(404, "not found"),
                    };
                }
                let Some(rel) = path.strip_prefix("/run/") else {
                    return Reply::Status(404, "not found");
                };
                match resolve_run_file(&self.root, rel) {
                    Some(file) => match File::open(&file) {
                        Ok(f) => Reply::File(f, content_type(&file)),
                        Err(_) => Reply::Status(404, "not found"),
                    },
                    None => Reply::Status(404, "not found"),
                }
            }
        }
    }
}

enum Reply {
    Bytes(Vec<u8>, &'static str),
    Static(&'static str, &'static str),
    File(File, &'static str),
    Status(u16, &'static str),
}

impl Reply {
    fn status(&self) -> u16 {
        match self {
            Self::Status(code, _) => *code,
            _ => 200,
        }
    }
}

fn with_type<R: std::io::Read>(r: Response<R>, kind: &str) -> Response<R> {
    let mut r = r;
    for (k, v) in [
        ("Content-Type", kind),
        ("X-Content-Type-Options", "nosniff"),
        ("Cache-Control", "no-store"),
    ] {
        if let Ok(h) = Header::from_bytes(k.as_bytes(), v.as_bytes()) {
            r = r.with_header(h);
        }
    }
    r
}

/// The file of the run folder `root` (canonical) that the URL path `rel` (after `/run/`,
/// percent-encoded) names, or `None` when it names no file inside it (module docs).
pub fn resolve_run_file(root: &Path, rel: &str) -> Option<PathBuf> {
    let decoded = percent_decode_str(rel).decode_utf8().ok()?;
    let mut path = root.to_path_buf();
    for segment in decoded.split('/') {
        if segment.is_empty() || segment == "." || segment == ".." || segment.contains(['\\', '\0'])
        {
            return None;
        }
        path.push(segment);
    }
    let real = path.canonicalize().ok()?;
    (real.starts_with(root) && real.is_file()).then_some(real)
}

/// Whether the request's `Host` (without its port) is an IP address, `localhost` or one of
/// `allowed`; a request without one (HTTP/1.0) passes.
fn host_allowed(request: &Request, allowed: &[String]) -> bool {
    let Some(host) = request
        .headers()
        .iter()
        .find(|h| h.field.equiv("Host"))
        .map(|h| h.value.as_str().to_ascii_lowercase())
    else {
        return true;
    };
    let name = if let Some(rest) = host.strip_prefix('[') {
        rest.split(']').next().unwrap_or("")
    } else {
        host.rsplit_once(':').map_or(host.as_str(), |(h, _)| h)
    };
    name == "localhost" || name.parse::<IpAddr>().is_ok() || allowed.iter().any(|a| a == name)
}

fn content_type(path: &Path) -> &'static str {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("html") => "text/html; charset=utf-8",
        Some("js") => "text/javascript; charset=utf-8",
        Some("json") => "application/json",
        Some("png") => "image/png",
        Some("gif") => "image/gif",
        Some("mp4") => "video/mp4",
        Some("csv") => "text/csv; charset=utf-8",
        Some("md") | Some("txt") => "text/plain; charset=utf-8",
        _ if path.file_name().is_some_and(|n| n == "LICENSE") => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    /// Only files inside the run folder resolve: `..` (plain or percent-encoded), absolute
    /// paths, empty and `.` segments, backslashes, directories and symlinks out of it do not.
    #[test]
    fn only_files_inside_the_run_folder_resolve() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("run");
        std::fs::create_dir_all(root.join("renders")).unwrap();
        std::fs::write(root.join("mesh.ply"), b"ply").unwrap();
        std::fs::write(root.join("renders/a b.png"), b"png").unwrap();
        std::fs::write(tmp.path().join("secret.txt"), b"secret").unwrap();
        #[cfg(unix)]
        std::os::unix::fs::symlink(tmp.path().join("secret.txt"), root.join("link.txt")).unwrap();
        let root = root.canonicalize().unwrap();
        assert_eq!(
            resolve_run_file(&root, "mesh.ply"),
            Some(root.join("mesh.ply"))
        );
        assert_eq!(
            resolve_run_file(&root, "renders/a%20b.png"),
            Some(root.join("renders/a b.png")),
            "a percent-encoded name resolves"
        );
        for bad in [
            "../secret.txt",
            "%2e%2e/secret.txt",
            "%2E%2E%2Fsecret.txt",
            "renders/../../secret.txt",
            "/etc/passwd",
            "%2fetc%2fpasswd",
            "..%5csecret.txt",
            "./mesh.ply",
            "renders//a%20b.png",
            "renders",
            "renders/",
            "",
            "mesh.ply%00.png",
            "link.txt",
            "missing.ply",
            "%ff%fe",
        ] {
            assert_eq!(
                resolve_run_file(&root, bad),
                None,
                "{bad:?} must not resolve to a file"
            );
        }
    }
}
