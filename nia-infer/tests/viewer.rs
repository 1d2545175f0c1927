//! `nia-infer view` as people use it: the server started on a free loopback port with a tiny
//! trained model, its routes (a PNG of the right size, JSON state, the source views, 4xx for
//! bad input, superseded requests), 20 concurrent clients with bounded memory, and headless
//! Chromium driven over the DevTools protocol: it opens the page, drags across the canvas
//! with real mouse input and the person is there and has turned.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Image size of the test subject's cameras.
const SIZE: u32 = 64;

/// A tiny model trained in-process on a synthetic set, exported: (folder, model file).
fn model() -> &'static (PathBuf, PathBuf) {
    static MODEL: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    MODEL.get_or_init(|| {
        let dir = common::fresh_dir("viewer");
        let (_, model) = common::train_tiny(&dir, SIZE, 5, false, &mut |_| {});
        (dir, model)
    })
}

/// A child process, killed and reaped on drop, then its scratch folder (if any) removed.
struct Running {
    child: Child,
    scratch: Option<PathBuf>,
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if let Some(dir) = &self.scratch {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// A running `nia-infer view`, killed on drop.
struct Viewer {
    process: Running,
    /// `127.0.0.1:PORT`
    address: String,
}

/// The viewer on the tiny model, or on `NIA_VIEWER_MODEL` with `NIA_VIEWER_DATA` and
/// `NIA_VIEWER_SUBJECT` (how the screenshot and timings of docs/speed.md were taken with the
/// quickstart model).
fn start_viewer() -> Viewer {
    let (model, data, subject) = match (
        std::env::var_os("NIA_VIEWER_MODEL"),
        std::env::var_os("NIA_VIEWER_DATA"),
        std::env::var("NIA_VIEWER_SUBJECT"),
    ) {
        (Some(m), Some(d), Ok(s)) => (PathBuf::from(m), PathBuf::from(d), s),
        _ => {
            let (dir, model) = model();
            (model.clone(), dir.join("data"), "CoreView_2".to_string())
        }
    };
    let mut child = Command::new(env!("CARGO_BIN_EXE_nia-infer"))
        .args(["view", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .args(["--subject", &subject, "--port", "0", "--chunk", "1024"])
        // 32 samples per ray at rest, so that a drag's frame takes a quarter of them.
        .args(["--samples", "32"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let address = line
        .trim()
        .strip_prefix("http://")
        .and_then(|a| a.strip_suffix('/'))
        .unwrap_or_else(|| panic!("the first line is the URL: {line:?}"))
        .to_string();
    assert!(
        address.starts_with("127.0.0.1:"),
        "loopback by default: {address}"
    );
    Viewer {
        process: Running {
            child,
            scratch: None,
        },
        address,
    }
}

/// Sends `request` to `address` (reads time out after 60 s): (the status line, the reader
/// after it).
fn send(address: &str, request: &str) -> (String, BufReader<TcpStream>) {
    let stream = TcpStream::connect(address).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    (&stream).write_all(request.as_bytes()).unwrap();
    let mut reader = BufReader::new(stream);
    let mut status_line = String::new();
    reader.read_line(&mut status_line).unwrap();
    (status_line, reader)
}

/// One HTTP/1.1 request: (status, headers in lower case, body).
fn http(address: &str, method: &str, target: &str) -> (u16, Vec<(String, String)>, Vec<u8>) {
    let request =
        format!("{method} {target} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n");
    // Headers, then Content-Length bytes (some servers keep the connection open).
    let (status_line, mut reader) = send(address, &request);
    let status: u16 = status_line
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("{target}: no status line: {status_line:?}"));
    let mut headers = Vec::new();
    loop {
        let mut line = String::new();
        reader.read_line(&mut line).unwrap();
        let line = line.trim_end();
        if line.is_empty() {
            break;
        }
        if let Some((k, v)) = line.split_once(':') {
            headers.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
        }
    }
    let length = headers
        .iter()
        .find(|(k, _)| k == "content-length")
        .and_then(|(_, v)| v.parse::<usize>().ok());
    let mut body = Vec::new();
    match length {
        Some(n) => {
            body.resize(n, 0);
            reader.read_exact(&mut body).unwrap();
        }
        None => {
            reader.read_to_end(&mut body).unwrap();
        }
    }
    (status, headers, body)
}

fn get(address: &str, target: &str) -> (u16, Vec<(String, String)>, Vec<u8>) {
    http(address, "GET", target)
}

fn png_size(bytes: &[u8]) -> (u32, u32) {
    let img = image::load_from_memory(bytes).expect("a PNG");
    (img.width(), img.height())
}

#[test]
fn routes_give_pngs_state_and_4xx_for_bad_input() {
    let v = start_viewer();
    let a = &v.address;
    let (status, _, body) = get(a, "/");
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&body).contains("<canvas"));
    let (status, _, body) = get(a, "/state");
    assert_eq!(status, 200);
    let state: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(state["frames"], 3);
    assert_eq!(state["views"], serde_json::json!([0, 1, 3]));
    assert_eq!(
        (state["width"].as_u64(), state["height"].as_u64()),
        (Some(64), Some(64))
    );

    for mode in ["color", "nerf", "blend", "opacity", "depth"] {
        let (status, headers, body) = get(
            a,
            &format!("/render?az=30&el=10&zoom=1.2&frame=2&mode={mode}&scale=0.5"),
        );
        assert_eq!(status, 200, "{mode}: {}", String::from_utf8_lossy(&body));
        assert_eq!(png_size(&body), (32, 32), "{mode}");
        let stats = headers
            .iter()
            .find(|(k, _)| k == "x-nia-stats")
            .map(|(_, v)| serde_json::from_str::<serde_json::Value>(v).unwrap())
            .expect("X-Nia-Stats");
        assert!(stats["point_evaluations"].as_u64().unwrap() > 0, "{stats}");
        assert!(stats["stage_ms"].as_object().is_some_and(|m| !m.is_empty()));
    }
    let (status, _, body) = get(a, "/render");
    assert_eq!(
        (status, png_size(&body)),
        (200, (64, 64)),
        "defaults: full size"
    );
    // A drag's frame: full size, the fast mode's samples per ray.
    let (status, headers, body) = get(a, "/render?fast=1");
    assert_eq!(
        (status, png_size(&body)),
        (200, (64, 64)),
        "fast: full size"
    );
    let samples = |headers: &[(String, String)]| {
        let stats = headers
            .iter()
            .find(|(k, _)| k == "x-nia-stats")
            .map(|(_, v)| serde_json::from_str::<serde_json::Value>(v).unwrap())
            .expect("X-Nia-Stats");
        stats["samples"].as_u64().unwrap() as usize
    };
    let (_, rest_headers, _) = get(a, "/render");
    assert_eq!(samples(&rest_headers), 32, "at rest: the session's samples");
    assert_eq!(samples(&headers), 8, "a drag's frame: a quarter of them");
    let (status, _, body) = get(a, "/source/1.png");
    assert_eq!((status, png_size(&body)), (200, (64, 64)));

    for (target, code, text) in [
        ("/render?az=abc", 400, "expected a number"),
        ("/render?zoom=99", 400, "zoom=99"),
        ("/render?frame=3", 400, "3 frames"),
        ("/render?mode=x", 400, "mode=x"),
        ("/render?scale=2", 400, "scale=2"),
        ("/render?fast=2", 400, "fast=2"),
        ("/render?a=%zz", 400, "percent"),
        ("/render?client=c&seq=x", 400, "seq"),
        ("/source/9.png", 404, "no such source"),
        ("/source/../../etc/passwd", 400, ".."),
        ("/%2e%2e/Cargo.toml", 400, ".."),
        ("/nope", 404, "not found"),
    ] {
        let (status, _, body) = get(a, target);
        let body = String::from_utf8_lossy(&body);
        assert_eq!(status, code, "{target}: {body}");
        assert!(body.contains(text), "{target}: {body}");
    }
    let (status, _, _) = http(a, "POST", "/render");
    assert_eq!(status, 405);
    // A newer request of a client supersedes its older ones.
    let (status, _, _) = get(a, "/render?scale=0.25&client=c1&seq=5");
    assert_eq!(status, 200);
    let (status, _, body) = get(a, "/render?scale=0.25&client=c1&seq=3");
    assert_eq!(status, 409, "{}", String::from_utf8_lossy(&body));
    // The server is still there.
    assert_eq!(get(a, "/state").0, 200);
}

/// Resident memory of a process, kB (Linux).
fn rss_kb(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

/// Requests per client of the load test.
const LOAD_REQUESTS: usize = 40;
/// Growth of the server's resident memory allowed over the load test: the pose cache (2
/// poses) and the allocator's high-water mark, not per-request leftovers.
const LOAD_RSS_GROWTH_KB: u64 = 300 * 1024;

#[test]
fn twenty_dragging_clients_keep_the_server_answering_with_bounded_memory() {
    let v = start_viewer();
    let a = v.address.clone();
    // Warm up (first renders, the pose cache), then measure.
    for frame in 0..3 {
        assert_eq!(get(&a, &format!("/render?scale=0.25&frame={frame}")).0, 200);
    }
    let before = rss_kb(v.process.child.id());
    let started = Instant::now();
    let threads: Vec<_> = (0..20)
        .map(|c| {
            let a = a.clone();
            std::thread::spawn(move || {
                let mut codes = Vec::new();
                for seq in 0..LOAD_REQUESTS {
                    let target = format!(
                        "/render?az={}&el={}&frame={}&scale=0.25&client=load{c}&seq={seq}",
                        (c * 37 + seq * 11) % 360,
                        (seq as i32 % 7) * 5,
                        (c + seq) % 3
                    );
                    codes.push(get(&a, &target).0);
                }
                codes
            })
        })
        .collect();
    let codes: Vec<u16> = threads
        .into_iter()
        .flat_map(|t| t.join().unwrap())
        .collect();
    let seconds = started.elapsed().as_secs_f64();
    assert_eq!(codes.len(), 20 * LOAD_REQUESTS);
    assert!(
        codes.iter().all(|&c| c == 200 || c == 409),
        "only renders and superseded requests: {codes:?}"
    );
    assert!(
        codes.iter().filter(|&&c| c == 200).count() >= 20,
        "{codes:?}"
    );
    assert_eq!(get(&a, "/state").0, 200, "still answering");
    let rendered = codes.iter().filter(|&&c| c == 200).count();
    if let (Some(b), Some(after)) = (before, rss_kb(v.process.child.id())) {
        eprintln!(
            "load: {} requests ({rendered} rendered, the rest superseded) in {seconds:.1} s, \
             RSS {b} -> {after} kB",
            codes.len()
        );
        assert!(after <= b + LOAD_RSS_GROWTH_KB, "RSS {b} -> {after} kB");
    }
}

// ---- headless Chromium over the DevTools protocol ----

/// The installed Chromium; None (the test is skipped, saying so) where there is none, unless
/// `NIA_REQUIRE_CHROMIUM=1`, where that fails the test.
fn chromium() -> Option<PathBuf> {
    let found = ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .map(PathBuf::from)
        .find(|c| {
            Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        });
    let required = std::env::var("NIA_REQUIRE_CHROMIUM").as_deref() == Ok("1");
    match found {
        None if required => panic!("NIA_REQUIRE_CHROMIUM=1 but no chromium is installed"),
        None => eprintln!("skipped: no chromium (apt-get install chromium)"),
        Some(_) => {}
    }
    found
}

/// A minimal WebSocket client (RFC 6455) for the DevTools session: the opening handshake,
/// masked text frames out, unmasked frames in (no extensions; continuation frames joined).
struct WebSocket {
    stream: BufReader<TcpStream>,
}

impl WebSocket {
    /// Connects to `ws://HOST:PORT/PATH`.
    fn connect(url: &str) -> WebSocket {
        let rest = url.strip_prefix("ws://").expect("a ws:// URL");
        let (host, path) = rest.split_at(rest.find('/').unwrap_or(rest.len()));
        let request = format!(
            "GET {path} HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: bmlhLXJzLXZpZXdlci10ZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        );
        let (status, mut reader) = send(host, &request);
        assert!(status.contains(" 101 "), "WebSocket handshake: {status}");
        loop {
            let mut line = String::new();
            reader.read_line(&mut line).unwrap();
            if line == "\r\n" || line.is_empty() {
                break;
            }
        }
        WebSocket { stream: reader }
    }

    fn send_text(&mut self, text: &str) {
        let payload = text.as_bytes();
        let mut frame = vec![0x81u8];
        let mask = [0x12u8, 0x34, 0x56, 0x78];
        match payload.len() {
            n if n < 126 => frame.push(0x80 | n as u8),
            n if n < 65536 => {
                frame.push(0x80 | 126);
                frame.extend_from_slice(&(n as u16).to_be_bytes());
            }
            n => {
                frame.push(0x80 | 127);
                frame.extend_from_slice(&(n as u64).to_be_bytes());
            }
        }
        frame.extend_from_slice(&mask);
        frame.extend(payload.iter().enumerate().map(|(i, b)| b ^ mask[i % 4]));
        self.stream.get_mut().write_all(&frame).unwrap();
    }

    /// The next whole text message.
    fn read_text(&mut self) -> String {
        let mut message = Vec::new();
        loop {
            let mut head = [0u8; 2];
            self.stream.read_exact(&mut head).unwrap();
            let (fin, opcode) = (head[0] & 0x80 != 0, head[0] & 0x0f);
            let len = match head[1] & 0x7f {
                126 => {
                    let mut b = [0u8; 2];
                    self.stream.read_exact(&mut b).unwrap();
                    u16::from_be_bytes(b) as usize
                }
                127 => {
                    let mut b = [0u8; 8];
                    self.stream.read_exact(&mut b).unwrap();
                    u64::from_be_bytes(b) as usize
                }
                n => n as usize,
            };
            let mut payload = vec![0u8; len];
            self.stream.read_exact(&mut payload).unwrap();
            match opcode {
                0x1 | 0x0 => message.extend_from_slice(&payload),
                0x8 => panic!("the browser closed the DevTools socket"),
                _ => continue, // ping/pong/binary: not used by DevTools here
            }
            if fin {
                return String::from_utf8(message).unwrap();
            }
        }
    }
}

/// A DevTools session on one page.
struct DevTools {
    socket: WebSocket,
    next: u64,
}

impl DevTools {
    fn call(&mut self, method: &str, params: serde_json::Value) -> serde_json::Value {
        self.next += 1;
        let id = self.next;
        let message = serde_json::json!({ "id": id, "method": method, "params": params });
        self.socket.send_text(&message.to_string());
        loop {
            let text = self.socket.read_text();
            let v: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
            if v["id"] == id {
                assert!(v.get("error").is_none(), "{method}: {v}");
                return v["result"].clone();
            }
        }
    }

    /// The value of a JavaScript expression (promises awaited).
    fn eval(&mut self, expression: &str) -> serde_json::Value {
        let r = self.call(
            "Runtime.evaluate",
            serde_json::json!({
                "expression": expression, "returnByValue": true, "awaitPromise": true
            }),
        );
        assert!(r.get("exceptionDetails").is_none(), "{expression}: {r}");
        r["result"]["value"].clone()
    }

    /// Waits until `expression` is true.
    fn wait_for(&mut self, expression: &str, what: &str) {
        let deadline = Instant::now() + Duration::from_secs(60);
        while self.eval(expression) != serde_json::json!(true) {
            assert!(Instant::now() < deadline, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn mouse(&mut self, kind: &str, x: f64, y: f64, buttons: u32) {
        self.call(
            "Input.dispatchMouseEvent",
            serde_json::json!({
                "type": kind, "x": x, "y": y, "button": "left", "buttons": buttons,
                "clickCount": if kind == "mouseMoved" { 0 } else { 1 }
            }),
        );
    }
}

/// A headless Chromium on `url`, killed on drop (its profile folder removed), with its DevTools
/// session.
fn open_browser(binary: &Path, url: &str) -> (Running, DevTools) {
    let profile = std::env::temp_dir().join(format!("nia-chromium-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&profile);
    std::fs::create_dir_all(&profile).unwrap();
    let child = Command::new(binary)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--remote-debugging-port=0",
            "--window-size=1000,720",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(url)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let port_file = profile.join("DevToolsActivePort");
    let browser = Running {
        child,
        scratch: Some(profile),
    };
    let deadline = Instant::now() + Duration::from_secs(60);
    let port = loop {
        if let Some(port) = std::fs::read_to_string(&port_file)
            .ok()
            .and_then(|t| t.lines().next().and_then(|l| l.trim().parse::<u16>().ok()))
        {
            break port;
        }
        assert!(
            Instant::now() < deadline,
            "Chromium did not open its DevTools port"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let devtools = format!("127.0.0.1:{port}");
    let page_ws = loop {
        let (_, _, body) = get(&devtools, "/json/list");
        let pages: serde_json::Value = serde_json::from_slice(&body).unwrap_or_default();
        if let Some(ws) = pages.as_array().and_then(|p| {
            p.iter()
                .find(|t| {
                    t["type"] == "page" && t["url"].as_str().is_some_and(|u| u.starts_with(url))
                })
                .and_then(|t| t["webSocketDebuggerUrl"].as_str().map(str::to_string))
        }) {
            break ws;
        }
        assert!(Instant::now() < deadline, "no page target: {pages}");
        std::thread::sleep(Duration::from_millis(100));
    };
    let socket = WebSocket::connect(&page_ws);
    (browser, DevTools { socket, next: 0 })
}

/// Counts lit canvas pixels; with `keep`, keeps the pixels as `window.__before`; with
/// `compare`, also counts pixels that differ from `window.__before`.
const CANVAS_STATS: &str = r#"(() => {
  const c = document.getElementById("view");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let lit = 0, changed = 0;
  const b = window.__before;
  for (let i = 0; i < d.length; i += 4) {
    if (d[i] + d[i + 1] + d[i + 2] > 6) lit++;
    if (b && Math.abs(d[i] - b[i]) + Math.abs(d[i + 1] - b[i + 1]) + Math.abs(d[i + 2] - b[i + 2]) > 6) changed++;
  }
  window.__before = d;
  const r = c.getBoundingClientRect();
  return { lit, changed, pixels: d.length / 4, x: r.left + r.width / 2, y: r.top + r.height / 2, full: +(c.dataset.full || 0), stats: document.getElementById("stats").textContent };
})()"#;

/// True once the page has drawn `n` full-size frames (false while it is still loading).
fn full_frames_at_least(n: u64) -> String {
    format!(
        "(() => {{ const c = document.getElementById('view'); \
         return !!c && +(c.dataset.full || 0) >= {n}; }})()"
    )
}

#[test]
fn chromium_drags_the_person_around() {
    let Some(binary) = chromium() else {
        return;
    };
    let v = start_viewer();
    let url = format!("http://{}/", v.address);
    let opened = Instant::now();
    let (_browser, mut dt) = open_browser(&binary, &url);
    dt.wait_for(&full_frames_at_least(1), "the first full frame");
    let first_picture = opened.elapsed().as_secs_f64();
    let before = dt.eval(CANVAS_STATS);
    let lit = before["lit"].as_u64().unwrap();
    assert!(lit > 100, "a person on the canvas: {before}");
    assert!(
        lit < before["pixels"].as_u64().unwrap(),
        "not a full-screen fill: {before}"
    );
    assert!(
        before["stats"].as_str().unwrap().contains("points"),
        "{before}"
    );

    // Drag right across the canvas with the left button held, as a person would.
    let (x, y) = (before["x"].as_f64().unwrap(), before["y"].as_f64().unwrap());
    let previews = "+(document.getElementById('view').dataset.previews || 0)";
    let previews_before = dt.eval(previews).as_u64().unwrap_or(0);
    let drag = Instant::now();
    dt.mouse("mousePressed", x - 120.0, y, 1);
    for i in 1..=40 {
        dt.mouse(
            "mouseMoved",
            x - 120.0 + 6.0 * i as f64,
            y + 0.3 * i as f64,
            1,
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let drag_seconds = drag.elapsed().as_secs_f64();
    let drawn = dt.eval(previews).as_u64().unwrap_or(0) - previews_before;
    dt.mouse("mouseReleased", x + 120.0, y + 12.0, 0);
    eprintln!(
        "first picture {first_picture:.2} s after opening the page (browser start included); \
         {drawn} preview frames in {drag_seconds:.1} s of dragging ({:.1} frames/s)",
        drawn as f64 / drag_seconds
    );
    assert!(drawn >= 1, "previews were drawn while dragging");
    let full_before = before["full"].as_u64().unwrap();
    dt.wait_for(
        &full_frames_at_least(full_before + 1),
        "the full frame after the drag",
    );
    let after = dt.eval(CANVAS_STATS);
    assert!(
        after["lit"].as_u64().unwrap() > 100,
        "still a person: {after}"
    );
    assert!(
        after["changed"].as_u64().unwrap() > 50,
        "the drag turned the view: {after}"
    );

    // The screenshot docs/speed.md shows.
    let shot = dt.call(
        "Page.captureScreenshot",
        serde_json::json!({ "format": "png" }),
    );
    let png = base64_decode(shot["data"].as_str().unwrap());
    assert!(image::load_from_memory(&png).is_ok());
    let path = std::env::var_os("NIA_VIEWER_SCREENSHOT")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_TARGET_TMPDIR")).join("viewer.png"));
    std::fs::write(&path, &png).unwrap();
    eprintln!("screenshot: {}", path.display());
}

/// Standard base64 (the DevTools screenshot).
fn base64_decode(text: &str) -> Vec<u8> {
    let value = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => (c - b'A') as u32,
            b'a'..=b'z' => (c - b'a') as u32 + 26,
            b'0'..=b'9' => (c - b'0') as u32 + 52,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        }
    };
    let bytes: Vec<u8> = text
        .bytes()
        .filter(|&c| c != b'=' && !c.is_ascii_whitespace())
        .collect();
    let mut out = Vec::with_capacity(bytes.len() * 3 / 4);
    for chunk in bytes.chunks(4) {
        let mut acc = 0u32;
        for (i, &c) in chunk.iter().enumerate() {
            acc |= value(c) << (18 - 6 * i);
        }
        let n = chunk.len() * 6 / 8;
        for i in 0..n {
            out.push((acc >> (16 - 8 * i)) as u8);
        }
    }
    out
}
