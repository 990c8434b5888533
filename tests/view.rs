//! `drbokeh view` (issue 40): the server and its HTTP API, from outside, as a browser or a
//! script uses them. The binary runs with `--port 0 --no-browser`; requests are plain
//! HTTP/1.0 over a TcpStream.

use crate::common;

use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::Duration;

/// The server process, killed when dropped.
struct Server {
    child: Child,
    addr: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Server {
    fn start(dir: &Path, args: &[&str]) -> Server {
        let mut c = common::drbokeh(dir);
        c.arg("view").args(args).args(["--port", "0", "--no-browser"]).stdout(Stdio::piped()).stderr(Stdio::piped());
        let mut child = c.spawn().expect("drbokeh view starts");
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        let line = rx.recv_timeout(Duration::from_secs(120)).expect("the server prints its URL");
        let url = line.trim().strip_prefix("listening on ").unwrap_or_else(|| panic!("first line: {line:?}"));
        // Loopback only.
        let addr = url.strip_prefix("http://127.0.0.1:").and_then(|r| r.strip_suffix('/')).unwrap_or_else(|| panic!("{url}"));
        Server { child, addr: format!("127.0.0.1:{addr}") }
    }

    /// `METHOD path` → (status, body).
    fn request(&self, method: &str, path: &str) -> (u16, Vec<u8>) {
        let mut s = TcpStream::connect(&self.addr).expect("connect");
        s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
        write!(s, "{method} {path} HTTP/1.0\r\nHost: localhost\r\nContent-Length: 0\r\n\r\n").unwrap();
        let mut all = Vec::new();
        s.read_to_end(&mut all).unwrap();
        let end = all.windows(4).position(|w| w == b"\r\n\r\n").expect("headers end");
        let head = String::from_utf8_lossy(&all[..end]).into_owned();
        let status = head.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or_else(|| panic!("{head}"));
        (status, all[end + 4..].to_vec())
    }

    fn json(&self, method: &str, path: &str) -> (u16, serde_json::Value) {
        let (status, body) = self.request(method, path);
        (status, serde_json::from_slice(&body).unwrap_or_else(|e| panic!("{path}: not JSON ({e}): {}", String::from_utf8_lossy(&body))))
    }
}

fn scene(dir: &Path) {
    let (w, h) = (64usize, 48usize);
    let mut rng = common::Rng::new(40);
    let rgb = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| 0.05 + 0.9 * rng.next_f32()).collect()).unwrap();
    let fg = |x: usize, y: usize| (x as f32 - 24.0).powi(2) + (y as f32 - 22.0).powi(2) < 121.0;
    let z =
        Image::from_vec(w, h, 1, (0..w * h).map(|i| if fg(i % w, i / w) { 1.0 } else { 3.0 + (i % w) as f32 / 32.0 }).collect()).unwrap();
    let m = Image::from_vec(w, h, 1, (0..w * h).map(|i| if fg(i % w, i / w) { 1.0 } else { 0.0 }).collect()).unwrap();
    io::write_exr(&dir.join("image.exr"), &rgb, &["R", "G", "B"]).unwrap();
    io::write_exr(&dir.join("depth.exr"), &z, &["Z"]).unwrap();
    io::write_png(&dir.join("matte.png"), &m, 8, Transfer::Linear).unwrap();
}

fn render_layers(dir: &Path, extra: &[&str]) -> Vec<u8> {
    let mut c = common::drbokeh(dir);
    c.args(["render", "--layer", "L/0_fg.exr", "--layer", "L/1_bg.exr", "-o", "one.png"]).args(extra);
    let out = common::run(c);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    std::fs::read(dir.join("one.png")).unwrap()
}

fn png_size(b: &[u8]) -> (u32, u32) {
    let img = image::load_from_memory(b).expect("a PNG");
    (img.width(), img.height())
}

#[test]
fn the_api_renders_what_render_renders_and_refuses_bad_requests() {
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    scene(d);
    let server = Server::start(d, &["image.exr", "--depth", "depth.exr", "--matte", "matte.png", "--save-layers", "L", "-o", "saved.png"]);
    // The page and its settings.
    let (status, page) = server.request("GET", "/");
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&page).contains("/render?"), "the page uses the API");
    let (status, info) = server.json("GET", "/info");
    assert_eq!(status, 200);
    assert_eq!((info["width"].as_u64(), info["height"].as_u64(), info["layers"].as_u64()), (Some(64), Some(48), Some(2)), "{info}");

    // /render at full size is `drbokeh render --layer` of the served layers, byte for byte,
    // for a click and for a focus value, with a profile and a quality.
    for (query, flags) in [
        ("focus_at=24,22&blur=6", vec!["--focus-at", "24,22", "--blur", "6"]),
        ("focus=0.1&blur=9&profile=official", vec!["--focus", "0.1", "--blur", "9", "--profile", "official"]),
        ("focus_at=60,5&blur=4&quality=5", vec!["--focus-at", "60,5", "--blur", "4", "--quality", "5"]),
        (
            "focus=0.2&blur=8&aperture=blades:5,rotation=90&anamorphic=1.3",
            vec!["--focus", "0.2", "--blur", "8", "--aperture", "blades:5,rotation=90", "--anamorphic", "1.3"],
        ),
        ("focus=0.1&blur=9&bubble=0.6", vec!["--focus", "0.1", "--blur", "9", "--bubble", "0.6"]),
        ("focus=0.1&blur=9&chromatic=0.1", vec!["--focus", "0.1", "--blur", "9", "--chromatic", "0.1"]),
        ("focus=0.1&blur=9&cat_eye=0.8", vec!["--focus", "0.1", "--blur", "9", "--cat-eye", "0.8"]),
    ] {
        let (status, png) = server.request("GET", &format!("/render?{query}"));
        assert_eq!(status, 200, "{query}: {}", String::from_utf8_lossy(&png));
        assert!(png == render_layers(d, &flags), "{query}: /render differs from drbokeh render --layer {flags:?}");
    }
    // A preview: the width asked for, the aspect ratio kept.
    let (status, png) = server.request("GET", "/render?focus_at=24,22&blur=6&width=32");
    assert_eq!((status, png_size(&png)), (200, (32, 24)));
    // The disparity a click picks: the subject's (near, 1) and the background's.
    let (_, j) = server.json("GET", "/depth?x=24&y=22");
    assert_eq!(j["disparity"].as_f64(), Some(1.0), "{j}");
    let (_, j) = server.json("GET", "/depth?x=63&y=0");
    assert!(j["disparity"].as_f64().unwrap() < 0.5, "{j}");
    let (status, png) = server.request("GET", "/overlay?kind=depth&width=16");
    assert_eq!((status, png_size(&png)), (200, (16, 12)));

    // Bad requests: 400 naming the parameter; unknown paths 404; wrong methods 405.
    for (path, needle) in [
        ("/render?focus=0.5&blur=3&bogus=1", "bogus"),
        ("/render?blur=3", "focus"),
        ("/render?focus=0.5&aperture=blades:2", "aperture"),
        ("/render?focus=0.5&bubble=2", "bubble"),
        ("/render?focus=0.5&bubble=x", "bubble"),
        ("/render?focus=0.5&chromatic=0.9", "chromatic"),
        ("/render?focus=0.5&cat_eye=2", "cat_eye"),
        ("/render?focus=0.5&focus_at=1,1", "focus_at"),
        ("/render?focus_at=64,1", "outside"),
        ("/render?focus_at=a,b", "focus_at"),
        ("/render?focus=nan", "focus"),
        ("/render?focus=0.5&blur=-1", "blur"),
        ("/render?focus=0.5&blur=1e9", "blur"),
        ("/render?focus=0.5&width=0", "width"),
        ("/render?focus=0.5&width=65", "width"),
        ("/render?focus=0.5&profile=fancy", "profile"),
        ("/render?focus=0.5&quality=9", "quality"),
        ("/depth?x=99&y=0", "outside"),
        ("/depth?x=1", "y"),
        ("/overlay?kind=colour", "kind"),
    ] {
        let (status, j) = server.json("GET", path);
        assert_eq!(status, 400, "{path}: {j}");
        assert!(j["error"].as_str().is_some_and(|e| e.contains(needle)), "{path}: {j}");
    }
    assert_eq!(server.request("GET", "/etc/passwd").0, 404);
    assert_eq!(server.request("GET", "/save?focus=0.5").0, 405);
    assert_eq!(server.request("DELETE", "/render?focus=0.5").0, 405);

    // Concurrent requests: each answer is its own focus's, as asked one at a time.
    let want: Vec<Vec<u8>> = (0..6).map(|k| server.request("GET", &format!("/render?focus={}&blur=7", k as f32 / 5.0)).1).collect();
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..6)
            .map(|k| {
                s.spawn({
                    let server = &server;
                    move || server.request("GET", &format!("/render?focus={}&blur=7", k as f32 / 5.0))
                })
            })
            .collect();
        for (k, h) in handles.into_iter().enumerate() {
            let (status, body) = h.join().unwrap();
            assert!(status == 200 && body == want[k], "concurrent request {k}");
        }
    });
    assert!(want.windows(2).all(|p| p[0] != p[1]), "the foci render differently");

    // Save: the output chosen at start, the render of those settings, and the command line.
    assert!(!d.join("saved.png").exists());
    let (status, j) = server.json("POST", "/save?focus_at=24,22&blur=6");
    assert_eq!(status, 200, "{j}");
    assert_eq!(j["path"], "saved.png");
    let cmd = j["command"].as_str().unwrap();
    assert!(
        cmd.starts_with("drbokeh render image.exr --depth depth.exr --matte matte.png")
            && cmd.contains("--focus-at 24,22 --blur 6 -o saved.png"),
        "{cmd}"
    );
    assert!(std::fs::read(d.join("saved.png")).unwrap() == render_layers(d, &["--focus-at", "24,22", "--blur", "6"]));
    // The look controls reach the command line (here the bubble), and it renders the same.
    let (status, j) = server.json("POST", "/save?focus=0.1&blur=9&bubble=0.6");
    assert_eq!(status, 200, "{j}");
    assert!(j["command"].as_str().unwrap().contains("--focus 0.1 --blur 9 --bubble 0.6 -o saved.png"), "{j}");
    assert!(std::fs::read(d.join("saved.png")).unwrap() == render_layers(d, &["--focus", "0.1", "--blur", "9", "--bubble", "0.6"]));
}

#[test]
fn view_refuses_bad_setups() {
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    scene(d);
    // The output may not be an input; a missing depth file is named.
    for (args, needle) in [
        (vec!["image.exr", "--depth", "depth.exr", "-o", "depth.exr"], "depth.exr"),
        (vec!["image.exr", "--depth", "missing.exr"], "missing.exr"),
    ] {
        let mut c = common::drbokeh(d);
        c.arg("view").args(&args).args(["--no-browser", "--port", "0"]);
        let out = common::run(c);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}

/// FNV-1a (32 bits), as the page computes it over a preview's bytes.
fn fnv1a(bytes: &[u8]) -> u32 {
    bytes.iter().fold(0x811c9dc5u32, |h, &b| (h ^ b as u32).wrapping_mul(0x01000193))
}

/// Chromium's headless shell: `$DRBOKEH_CHROMIUM`, else the one `scripts/setup-test-env.sh`
/// unpacks into `.tools/chromium` (run with its libraries on LD_LIBRARY_PATH).
fn chromium() -> std::process::Command {
    if let Ok(p) = std::env::var("DRBOKEH_CHROMIUM") {
        return std::process::Command::new(p);
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools/chromium/usr");
    let bin = root.join("lib/chromium/chromium-headless-shell");
    assert!(bin.exists(), "{} is missing: run scripts/setup-test-env.sh (or set DRBOKEH_CHROMIUM)", bin.display());
    let libs = [root.join("lib/x86_64-linux-gnu"), root.join("lib/x86_64-linux-gnu/pulseaudio")];
    let mut path = std::env::join_paths(libs).unwrap();
    if let Some(old) = std::env::var_os("LD_LIBRARY_PATH") {
        path = std::env::join_paths(std::env::split_paths(&path).chain(std::env::split_paths(&old))).unwrap();
    }
    let mut c = std::process::Command::new(bin);
    c.env("LD_LIBRARY_PATH", path);
    c
}

/// Chromium's headless shell driven over the DevTools protocol on a pipe (`--remote-debugging-pipe`:
/// it reads commands on fd 3 and writes answers on fd 4, each a JSON text ended by a NUL). The
/// test waits on the page in real time, so a loaded machine slows it down without cutting it
/// short (as `--virtual-time-budget` with `--dump-dom` did once in CI), and its click is a
/// real mouse event at a point of the window.
struct Browser {
    child: Child,
    to: std::io::PipeWriter,
    from: BufReader<std::io::PipeReader>,
    next: u64,
    session: String,
    _profile: tempfile::TempDir,
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Browser {
    /// Opens `url` in a 900x700 window and attaches to its page.
    fn open(url: &str) -> Browser {
        use std::os::fd::AsRawFd;
        use std::os::unix::process::CommandExt;
        let (cmd_r, cmd_w) = std::io::pipe().unwrap();
        let (ans_r, ans_w) = std::io::pipe().unwrap();
        let profile = tempfile::tempdir().unwrap();
        let mut c = chromium();
        c.args(["--no-sandbox", "--disable-gpu", "--window-size=900,700", "--remote-debugging-pipe"])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg(url)
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        let (r, w) = (cmd_r.as_raw_fd(), ans_w.as_raw_fd());
        // SAFETY: fcntl and dup2 are async-signal-safe. The ends are first copied above 10, as
        // they may themselves be fds 3 or 4; the copies at 3 and 4 lose close-on-exec.
        unsafe {
            c.pre_exec(move || {
                let (r, w) = (libc::fcntl(r, libc::F_DUPFD, 10), libc::fcntl(w, libc::F_DUPFD, 10));
                if r < 0 || w < 0 || libc::dup2(r, 3) < 0 || libc::dup2(w, 4) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = c.spawn().expect("Chromium runs");
        drop((cmd_r, ans_w));
        let mut b = Browser { child, to: cmd_w, from: BufReader::new(ans_r), next: 0, session: String::new(), _profile: profile };
        let targets = b.call("Target.getTargets", serde_json::json!({}));
        let page = targets["targetInfos"]
            .as_array()
            .and_then(|t| t.iter().find(|t| t["type"] == "page"))
            .unwrap_or_else(|| panic!("no page among {targets}"))["targetId"]
            .clone();
        let attached = b.call("Target.attachToTarget", serde_json::json!({"targetId": page, "flatten": true}));
        b.session = attached["sessionId"].as_str().unwrap().to_string();
        b
    }

    /// Sends a command (to the page once attached) and returns its result; events and other
    /// answers on the way are skipped.
    fn call(&mut self, method: &str, params: serde_json::Value) -> serde_json::Value {
        self.next += 1;
        let mut msg = serde_json::json!({"id": self.next, "method": method, "params": params});
        if !self.session.is_empty() {
            msg["sessionId"] = self.session.clone().into();
        }
        self.to.write_all(msg.to_string().as_bytes()).unwrap();
        self.to.write_all(b"\0").unwrap();
        loop {
            let mut buf = Vec::new();
            let n = self.from.read_until(0, &mut buf).unwrap();
            assert!(n > 0, "Chromium closed its pipe during {method}");
            let answer: serde_json::Value = serde_json::from_slice(&buf[..buf.len() - 1]).unwrap();
            if answer["id"] == self.next {
                assert!(answer.get("error").is_none(), "{method}: {answer}");
                return answer["result"].clone();
            }
        }
    }

    /// The value of a JavaScript expression on the page.
    fn eval(&mut self, expression: &str) -> serde_json::Value {
        let r = self.call("Runtime.evaluate", serde_json::json!({"expression": expression, "returnByValue": true}));
        r["result"]["value"].clone()
    }

    /// Polls `expression` until it is true, for at most two minutes of real time.
    fn wait_for(&mut self, expression: &str) {
        let start = std::time::Instant::now();
        while self.eval(expression) != serde_json::Value::Bool(true) {
            if start.elapsed() > Duration::from_secs(120) {
                panic!("waited 2 min for {expression}:\n{}", self.eval("document.documentElement.outerHTML"));
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// A left click of the mouse at (x, y) CSS pixels of the window.
    fn click(&mut self, x: f64, y: f64) {
        for kind in ["mousePressed", "mouseReleased"] {
            let p = serde_json::json!({"type": kind, "x": x, "y": y, "button": "left", "clickCount": 1});
            self.call("Input.dispatchMouseEvent", p);
        }
    }
}

/// The page in a real (headless) browser: it loads, shows a first preview (focused on the
/// subject at the centre), a mouse click on the background refocuses there, and the preview it
/// shows is byte for byte what `/render` answers for that click's query (checked through the
/// FNV-1a the page keeps of its bytes), after a quick one at quality 1 that is `/render`'s
/// answer to the same query at quality 1.
#[test]
fn the_page_refocuses_where_clicked_in_a_browser() {
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    scene(d);
    let server = Server::start(d, &["image.exr", "--depth", "depth.exr", "--matte", "matte.png"]);
    let mut browser = Browser::open(&format!("http://{}/", server.addr));
    let status = |b: &mut Browser, key: &str| b.eval(&format!("document.getElementById('status').dataset.{key} || ''"));
    browser.wait_for("document.getElementById('status').dataset.renders === '1'");
    let first = status(&mut browser, "sum");
    // A click on the background at pixel (55, 40) of the 64x48 photo, placed on the image as
    // the page shows it.
    let r = browser.eval(
        "(() => { const r = document.getElementById('view').getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })()",
    );
    let r: Vec<f64> = r.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert!(r[2] >= 64.0 && r[3] >= 48.0, "the preview is shown whole: {r:?}");
    browser.click(r[0] + 55.5 / 64.0 * r[2], r[1] + 40.5 / 48.0 * r[3]);
    browser.wait_for("document.getElementById('status').dataset.renders === '2'");
    let query = status(&mut browser, "query").as_str().unwrap().to_string();
    // The browser places the click within a pixel of (55, 40) (the shown image's position is
    // fractional): on the background either way.
    let xy = query.split('&').find_map(|kv| kv.strip_prefix("focus_at=")).unwrap_or_else(|| panic!("{query}")).replace("%2C", ",");
    let (x, y) = xy.split_once(',').map(|(x, y)| (x.parse::<i64>().unwrap(), y.parse::<i64>().unwrap())).unwrap();
    assert!((x - 55).abs() <= 1 && (y - 40).abs() <= 1, "the click focuses near 55,40: {query}");
    let (_, j) = server.json("GET", &format!("/depth?x={x}&y={y}"));
    assert!(j["disparity"].as_f64().unwrap() < 0.5, "the click is on the background: {j}");
    let (code, png) = server.request("GET", &format!("/render?{query}"));
    assert_eq!(code, 200);
    assert_eq!(status(&mut browser, "bytes"), png.len().to_string());
    assert_eq!(status(&mut browser, "sum"), fnv1a(&png).to_string(), "the preview shown is /render's answer");
    assert_ne!(first, status(&mut browser, "sum"), "the click changed the preview");
    // Before it, the page showed the quick preview of the same click: the same query at
    // quality 1 (the default quality is 2), byte for byte /render's answer to it.
    let quick = status(&mut browser, "quickQuery").as_str().unwrap().to_string();
    assert_eq!(quick, query.replace("quality=2", "quality=1"), "the quick preview is the click's query at quality 1");
    assert!(query.contains("quality=2"), "{query}");
    let (code, png) = server.request("GET", &format!("/render?{quick}"));
    assert_eq!(code, 200);
    assert_eq!(status(&mut browser, "quickSum"), fnv1a(&png).to_string(), "the quick preview shown is /render's answer");
}
