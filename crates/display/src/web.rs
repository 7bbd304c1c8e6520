//! A local web viewer: a small HTTP server on a loopback address serving a
//! page that refreshes the screen image and the status every half second.
//!
//! Routes: `/` (the page), `/screen.png` (the latest screen), `/status.json`.
//! It only shows: no route changes anything, and none reaches the axis. On
//! a loopback address anyone on the machine may look; on any other address
//! every request must carry `?token=T`, a random token drawn at start and
//! given in [`WebViewer::url`], or it is answered 403.
//!
//! HTTP is `tiny_http`'s (keep-alive, request parsing with bounded
//! headers); [`WORKERS`] threads answer, so one slow client does not hold
//! up the others.

use std::io;
use std::sync::{Arc, Mutex};

use tiny_http::{Header, Request, Response, Server};

use stereolink_image::{io as imgio, RgbImage};

use crate::screen::ScreenStatus;
use crate::sinks::Sink;

const PAGE: &str = r#"<!doctype html>
<html><head><meta charset="utf-8"><title>stereolink receiver</title>
<style>body{background:#101218;color:#e6e6e6;font-family:sans-serif;margin:16px}
img{image-rendering:pixelated;width:960px;height:544px;border:1px solid #444}</style></head>
<body><h1>stereolink receiver</h1>
<img id="screen" src="/screen.png" alt="receiver screen">
<pre id="status">waiting for the first frame…</pre>
<script>
const q = location.search.includes('token=') ? '?token=' + new URLSearchParams(location.search).get('token') : '';
async function tick(){
  try{
    const s = await (await fetch('/status.json' + q,{cache:'no-store'})).json();
    document.getElementById('status').textContent = JSON.stringify(s, null, 1);
    document.getElementById('screen').src = '/screen.png' + q + (q ? '&' : '?') + 'frame=' + s.frame_id;
  }catch(e){}
}
setInterval(tick, 500); tick();
</script></body></html>
"#;

/// Threads answering requests.
pub const WORKERS: usize = 4;

#[derive(Default)]
struct State {
    png: Vec<u8>,
    status: String,
}

/// The viewer: serves until dropped (the server thread then exits with the process).
pub struct WebViewer {
    addr: String,
    /// Required on a non-loopback address.
    token: Option<String>,
    state: Arc<Mutex<State>>,
}

impl WebViewer {
    /// Starts serving on `addr` (e.g. `127.0.0.1:8080`; port 0 picks one).
    pub fn start(addr: &str) -> io::Result<Self> {
        let server = Arc::new(Server::http(addr).map_err(io::Error::other)?);
        let local = server
            .server_addr()
            .to_ip()
            .ok_or_else(|| io::Error::other("the viewer is not on an IP address"))?;
        let token = match local.ip().is_loopback() {
            true => None,
            false => Some(random_token()?),
        };
        let addr = local.to_string();
        let state = Arc::new(Mutex::new(State {
            png: imgio::encode_png_rgb(&RgbImage::new(480, 272, [16, 18, 24])),
            status: "{\"frame_id\":0}".into(),
        }));
        for _ in 0..WORKERS {
            let (server, shared, required) = (server.clone(), state.clone(), token.clone());
            std::thread::spawn(move || {
                for request in server.incoming_requests() {
                    let _ = answer(request, &shared, required.as_deref());
                }
            });
        }
        Ok(WebViewer { addr, token, state })
    }

    /// The address it serves on, with the token when one is required.
    pub fn url(&self) -> String {
        match &self.token {
            Some(t) => format!("http://{}/?token={t}", self.addr),
            None => format!("http://{}/", self.addr),
        }
    }
}

/// 128 bits from the OS, in hex.
fn random_token() -> io::Result<String> {
    let mut bytes = [0u8; 16];
    io::Read::read_exact(&mut std::fs::File::open("/dev/urandom")?, &mut bytes)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// Whether the request's query carries `token` (compared in constant time).
fn authorised(query: &str, token: Option<&str>) -> bool {
    let Some(token) = token else { return true };
    query.split('&').any(|kv| {
        kv.strip_prefix("token=").is_some_and(|t| {
            t.len() == token.len()
                && t.bytes()
                    .zip(token.bytes())
                    .fold(0, |d, (a, b)| d | (a ^ b))
                    == 0
        })
    })
}

fn answer(request: Request, state: &Mutex<State>, token: Option<&str>) -> io::Result<()> {
    let target = request.url().to_string();
    let (path, query) = target.split_once('?').unwrap_or((&target, ""));
    let path = if authorised(query, token) {
        path
    } else {
        "forbidden"
    };
    let (status, kind, body): (u16, &str, Vec<u8>) = {
        let s = state
            .lock()
            .map_err(|_| io::Error::other("viewer state poisoned"))?;
        match path {
            "/" | "/index.html" => (200, "text/html; charset=utf-8", PAGE.as_bytes().to_vec()),
            "/screen.png" => (200, "image/png", s.png.clone()),
            "/status.json" => (200, "application/json", s.status.clone().into_bytes()),
            "forbidden" => (
                403,
                "text/plain",
                b"this viewer needs the token printed at its start: open the URL given there"
                    .to_vec(),
            ),
            _ => (404, "text/plain", b"not found".to_vec()),
        }
    };
    let header = |name: &str, value: &str| {
        Header::from_bytes(name.as_bytes(), value.as_bytes()).expect("a valid header")
    };
    let response = Response::from_data(body)
        .with_status_code(status)
        .with_header(header("Content-Type", kind))
        .with_header(header("Cache-Control", "no-store"));
    request.respond(response)
}

impl Sink for WebViewer {
    fn show(&mut self, screen: &RgbImage, status: &ScreenStatus) -> io::Result<()> {
        let png = imgio::encode_png_rgb(screen);
        let json = serde_json::to_string(status).map_err(io::Error::other)?;
        let mut s = self
            .state
            .lock()
            .map_err(|_| io::Error::other("viewer state poisoned"))?;
        s.png = png;
        s.status = json;
        Ok(())
    }

    fn describe(&self) -> String {
        format!("web viewer at {}", self.url())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};
    use std::net::TcpStream;

    fn get(addr: &str, path: &str) -> (String, Vec<u8>) {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(
            s,
            "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
        )
        .unwrap();
        let mut buf = Vec::new();
        s.read_to_end(&mut buf).unwrap();
        let split = buf.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        (
            String::from_utf8_lossy(&buf[..split]).into_owned(),
            buf[split + 4..].to_vec(),
        )
    }

    #[test]
    fn serves_page_image_and_status() {
        let mut v = WebViewer::start("127.0.0.1:0").unwrap();
        let addr = v.addr.clone();
        v.show(
            &RgbImage::new(480, 272, [0, 255, 0]),
            &ScreenStatus {
                frame_id: 9,
                ..Default::default()
            },
        )
        .unwrap();
        let (h, body) = get(&addr, "/");
        assert!(h.contains("200") && String::from_utf8_lossy(&body).contains("screen.png"));
        let (h, png) = get(&addr, "/screen.png?frame=9");
        assert!(h.contains("image/png"));
        assert_eq!(imgio::decode_rgb(&png).unwrap().get(10, 10), [0, 255, 0]);
        let (_, status) = get(&addr, "/status.json");
        assert!(String::from_utf8_lossy(&status).contains("\"frame_id\":9"));
        assert!(get(&addr, "/nope").0.contains("404"));
        assert!(v.url().ends_with('/'), "no token on loopback: {}", v.url());
    }

    #[test]
    fn beyond_loopback_every_route_needs_the_token() {
        let v = WebViewer::start("0.0.0.0:0").unwrap();
        let port = v.addr.rsplit(':').next().unwrap().to_string();
        let addr = format!("127.0.0.1:{port}");
        let token = v.url().split("token=").nth(1).unwrap().to_string();
        assert_eq!(token.len(), 32);
        for path in ["/", "/screen.png", "/status.json"] {
            assert!(get(&addr, path).0.contains("403"), "{path}");
            assert!(get(&addr, &format!("{path}?token=00{}", &token[2..]))
                .0
                .contains("403"));
            let (h, _) = get(&addr, &format!("{path}?token={token}&frame=1"));
            assert!(h.contains("200"), "{path}: {h}");
        }
        // Nothing but GET-style reads exist: any other path is unknown.
        assert!(get(&addr, &format!("/axis?token={token}"))
            .0
            .contains("404"));
    }
}
