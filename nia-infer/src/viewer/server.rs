//! The viewer's HTTP server (tiny_http, a fixed pool of worker threads): routes, parameter
//! checks and the per-client cancellation of stale renders.
//!
//! - `GET /`: the page;
//! - `GET /state`: JSON (subject, frames, reference frame, source views, image size, modes);
//! - `GET /render?az=&el=&zoom=&frame=&mode=&scale=&fast=&client=&seq=`: a PNG, its cost in
//!   the `X-Nia-Stats` header (JSON); `409` when a newer request of the same client superseded
//!   it; `fast=1` renders a drag's frame (one coloured sample per ray, one ray per pixel);
//! - `GET /source/K.png`: source view K (an index into the state's `views`).
//!
//! Anything else is a 4xx with a plain-text message: unknown routes (404), methods other than
//! GET (405), `..` in a path or malformed or out-of-range parameters (400). Nothing is read
//! from disk after start-up, so no path can reach a file.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use tiny_http::{Header, Method, Request, Response, Server};

use super::{Mode, ViewRequest, ViewerScene, MAX_ELEVATION, PAGE, SCALE_RANGE, ZOOM_RANGE};

/// Worker threads answering requests (renders themselves run one at a time).
pub const WORKERS: usize = 8;
/// Clients whose latest request number is remembered (the oldest are forgotten beyond).
const MAX_CLIENTS: usize = 1024;

/// The shared state of the workers.
pub struct Viewer {
    scene: Mutex<ViewerScene>,
    /// Latest `seq` seen per client.
    latest: Mutex<HashMap<String, u64>>,
    /// `/state`, made once (answered while a render holds the scene).
    state: serde_json::Value,
    /// The source views as PNGs.
    sources: Vec<Vec<u8>>,
    frames: usize,
    reference: usize,
}

impl Viewer {
    pub fn new(scene: ViewerScene) -> Self {
        let cam = &scene.session.opened.subject().cameras[0];
        let state = serde_json::json!({
            "subject": scene.session.opened.subject().name,
            "frames": scene.num_frames(),
            "reference_frame": scene.reference_frame,
            "views": scene.session.views,
            "width": cam.width,
            "height": cam.height,
            "modes": Mode::ALL.iter().map(|m| m.name()).collect::<Vec<_>>(),
            "view_colours": super::VIEW_COLOURS,
            "max_elevation_deg": MAX_ELEVATION.to_degrees(),
            "zoom_range": ZOOM_RANGE,
            "scale_range": SCALE_RANGE,
            "encode_seconds": scene.encode_seconds,
            "model": scene.session.loaded.path,
            "step": scene.session.loaded.step,
        });
        let sources = (0..scene.session.views.len())
            .filter_map(|k| scene.source_png(k))
            .collect();
        Viewer {
            frames: scene.num_frames(),
            reference: scene.reference_frame,
            scene: Mutex::new(scene),
            latest: Mutex::new(HashMap::new()),
            state,
            sources,
        }
    }

    /// Records `seq` as `client`'s latest unless a newer one is known; whether it is current.
    fn announce(&self, client: &str, seq: u64) -> bool {
        let mut latest = self.latest.lock().unwrap_or_else(|e| e.into_inner());
        if latest.len() >= MAX_CLIENTS && !latest.contains_key(client) {
            latest.clear();
        }
        let entry = latest.entry(client.to_string()).or_insert(seq);
        if seq >= *entry {
            *entry = seq;
            true
        } else {
            false
        }
    }

    fn is_stale(&self, client: &str, seq: u64) -> bool {
        let latest = self.latest.lock().unwrap_or_else(|e| e.into_inner());
        latest.get(client).is_some_and(|&l| l > seq)
    }
}

/// A response: status, content type, body, extra headers.
pub struct Reply {
    pub status: u16,
    pub content_type: &'static str,
    pub body: Vec<u8>,
    pub headers: Vec<(&'static str, String)>,
}

impl Reply {
    fn text(status: u16, message: impl Into<String>) -> Self {
        Reply {
            status,
            content_type: "text/plain; charset=utf-8",
            body: message.into().into_bytes(),
            headers: Vec::new(),
        }
    }
    fn json(value: serde_json::Value) -> Self {
        Reply {
            status: 200,
            content_type: "application/json",
            body: value.to_string().into_bytes(),
            headers: Vec::new(),
        }
    }
}

/// The `key=value` pairs of a query string, percent-decoded.
fn query_pairs(query: &str) -> Result<HashMap<String, String>, String> {
    let mut out = HashMap::new();
    for pair in query.split('&').filter(|p| !p.is_empty()) {
        let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
        out.insert(decode(k)?, decode(v)?);
    }
    Ok(out)
}

fn decode(s: &str) -> Result<String, String> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'%' => {
                let hex = s
                    .get(i + 1..i + 3)
                    .and_then(|h| u8::from_str_radix(h, 16).ok())
                    .ok_or_else(|| format!("bad percent escape in `{s}`"))?;
                out.push(hex);
                i += 3;
            }
            b'+' => {
                out.push(b' ');
                i += 1;
            }
            b => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).map_err(|_| format!("`{s}` is not UTF-8"))
}

/// A finite number parameter in `[lo, hi]`, or its default when absent.
fn number(
    q: &HashMap<String, String>,
    key: &str,
    default: f32,
    (lo, hi): (f32, f32),
) -> Result<f32, String> {
    let Some(text) = q.get(key) else {
        return Ok(default);
    };
    let v: f32 = text
        .parse()
        .map_err(|_| format!("`{key}={text}`: expected a number"))?;
    if !(v.is_finite() && (lo..=hi).contains(&v)) {
        return Err(format!("`{key}={text}`: expected a number in [{lo}, {hi}]"));
    }
    Ok(v)
}

/// Checks the parameters of `/render`.
pub fn view_request(
    q: &HashMap<String, String>,
    frames: usize,
    reference: usize,
) -> Result<ViewRequest, String> {
    let azimuth = number(q, "az", 0.0, (-1e4, 1e4))?;
    let max_el = MAX_ELEVATION.to_degrees();
    let elevation = number(q, "el", 0.0, (-max_el, max_el))?;
    let zoom = number(q, "zoom", 1.0, ZOOM_RANGE)?;
    let scale = number(q, "scale", 1.0, SCALE_RANGE)?;
    let fast = match q.get("fast").map(String::as_str) {
        None | Some("0") => false,
        Some("1") => true,
        Some(other) => return Err(format!("`fast={other}`: expected 0 or 1")),
    };
    let frame = match q.get("frame") {
        None => reference,
        Some(text) => {
            let f: usize = text
                .parse()
                .map_err(|_| format!("`frame={text}`: expected a frame index"))?;
            if f >= frames {
                return Err(format!(
                    "`frame={f}`: the subject has {frames} frames (0..{})",
                    frames - 1
                ));
            }
            f
        }
    };
    let mode = match q.get("mode").map(String::as_str) {
        None => Mode::Color,
        Some(name) => *Mode::ALL.iter().find(|m| m.name() == name).ok_or_else(|| {
            let names: Vec<&str> = Mode::ALL.iter().map(|m| m.name()).collect();
            format!("`mode={name}`: expected one of {}", names.join(", "))
        })?,
    };
    Ok(ViewRequest {
        azimuth: azimuth.to_radians(),
        elevation: elevation.to_radians().clamp(-MAX_ELEVATION, MAX_ELEVATION),
        zoom,
        frame,
        mode,
        scale,
        fast,
    })
}

/// Answers one request.
pub fn answer(viewer: &Viewer, method: &Method, url: &str) -> Reply {
    if *method != Method::Get {
        return Reply::text(405, format!("{method} {url}: only GET is served"));
    }
    let (path, query) = url.split_once('?').unwrap_or((url, ""));
    if path.split('/').any(|part| part == "..") || decode(path).is_ok_and(|p| p.contains("..")) {
        return Reply::text(400, format!("{path}: `..` is not allowed in a path"));
    }
    let q = match query_pairs(query) {
        Ok(q) => q,
        Err(e) => return Reply::text(400, e),
    };
    match path {
        "/" | "/index.html" => Reply {
            status: 200,
            content_type: "text/html; charset=utf-8",
            body: PAGE.as_bytes().to_vec(),
            headers: Vec::new(),
        },
        "/state" => Reply::json(viewer.state.clone()),
        "/render" => render(viewer, &q),
        _ => {
            if let Some(name) = path.strip_prefix("/source/") {
                let index = name
                    .strip_suffix(".png")
                    .and_then(|k| k.parse::<usize>().ok());
                return match index.and_then(|k| viewer.sources.get(k)) {
                    Some(png) => Reply {
                        status: 200,
                        content_type: "image/png",
                        body: png.clone(),
                        headers: Vec::new(),
                    },
                    None => Reply::text(
                        404,
                        format!(
                            "{path}: no such source view (0..{} as /source/K.png)",
                            viewer.sources.len().saturating_sub(1)
                        ),
                    ),
                };
            }
            Reply::text(
                404,
                format!("{path}: not found (/, /state, /render, /source/K.png)"),
            )
        }
    }
}

fn render(viewer: &Viewer, q: &HashMap<String, String>) -> Reply {
    let request = match view_request(q, viewer.frames, viewer.reference) {
        Ok(r) => r,
        Err(e) => return Reply::text(400, e),
    };
    let client = q.get("client").cloned().unwrap_or_default();
    let seq = match q.get("seq").map(|s| s.parse::<u64>()) {
        None => 0,
        Some(Ok(s)) => s,
        Some(Err(_)) => return Reply::text(400, "`seq`: expected a request number"),
    };
    let tracked = !client.is_empty();
    if tracked && !viewer.announce(&client, seq) {
        return Reply::text(409, "superseded by a newer request of this client");
    }
    let cancelled = || tracked && viewer.is_stale(&client, seq);
    if cancelled() {
        return Reply::text(409, "superseded by a newer request of this client");
    }
    let mut scene = viewer.scene.lock().unwrap_or_else(|e| e.into_inner());
    match scene.render(&request, &cancelled) {
        Ok(Some(frame)) => Reply {
            status: 200,
            content_type: "image/png",
            body: frame.png,
            headers: vec![(
                "X-Nia-Stats",
                serde_json::to_string(&frame.stats).unwrap_or_default(),
            )],
        },
        Ok(None) => Reply::text(409, "superseded by a newer request of this client"),
        Err(e) => Reply::text(500, format!("rendering failed: {e:#}")),
    }
}

fn respond(request: Request, reply: Reply) {
    let mut response = Response::from_data(reply.body).with_status_code(reply.status);
    let mut headers = vec![("Content-Type", reply.content_type.to_string())];
    headers.push(("Cache-Control", "no-store".into()));
    headers.extend(reply.headers);
    for (k, v) in headers {
        if let Ok(h) = Header::from_bytes(k.as_bytes(), v.as_bytes()) {
            response.add_header(h);
        }
    }
    // A client that hung up is not an error of the server.
    let _ = request.respond(response);
}

/// Serves `viewer` on `server` with [`WORKERS`] threads until the server is unblocked.
pub fn serve(server: Arc<Server>, viewer: Arc<Viewer>) {
    let workers: Vec<_> = (0..WORKERS)
        .map(|_| {
            let server = server.clone();
            let viewer = viewer.clone();
            std::thread::spawn(move || {
                while let Ok(request) = server.recv() {
                    let reply = answer(&viewer, request.method(), request.url());
                    respond(request, reply);
                }
            })
        })
        .collect();
    for w in workers {
        let _ = w.join();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn q(s: &str) -> HashMap<String, String> {
        query_pairs(s).unwrap()
    }

    #[test]
    fn view_parameters_are_checked() {
        let r = view_request(
            &q("az=90&el=10&zoom=1.5&frame=2&mode=blend&scale=0.25"),
            6,
            0,
        )
        .unwrap();
        assert!((r.azimuth - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert_eq!(
            (r.frame, r.mode, r.zoom, r.scale),
            (2, Mode::Blend, 1.5, 0.25)
        );
        let defaults = view_request(&q(""), 6, 3).unwrap();
        assert_eq!(
            (defaults.frame, defaults.mode, defaults.scale),
            (3, Mode::Color, 1.0)
        );
        for (bad, what) in [
            ("az=abc", "expected a number"),
            ("az=nan", "expected a number in"),
            ("zoom=9", "[0.3, 3]"),
            ("scale=0", "scale=0"),
            ("frame=6", "6 frames"),
            ("frame=-1", "frame index"),
            ("mode=x", "color, nerf, blend, opacity, depth"),
            ("el=100", "el=100"),
        ] {
            let e = view_request(&q(bad), 6, 0).unwrap_err();
            assert!(e.contains(what), "{bad}: {e}");
        }
        assert!(query_pairs("a=%zz").is_err());
        assert_eq!(q("a=%41+b")["a"], "A b");
    }
}
