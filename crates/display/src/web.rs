//! A local web viewer: a small HTTP server on a loopback address serving a
//! page that refreshes the screen image and the status every half second.
//!
//! Routes: `/` (the page), `/screen.png` (the latest screen), `/status.json`.

use std::io::{self, BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Mutex};

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
async function tick(){
  try{
    const s = await (await fetch('/status.json',{cache:'no-store'})).json();
    document.getElementById('status').textContent = JSON.stringify(s, null, 1);
    document.getElementById('screen').src = '/screen.png?frame=' + s.frame_id;
  }catch(e){}
}
setInterval(tick, 500); tick();
</script></body></html>
"#;

#[derive(Default)]
struct State {
    png: Vec<u8>,
    status: String,
}

/// The viewer: serves until dropped (the server thread then exits with the process).
pub struct WebViewer {
    addr: String,
    state: Arc<Mutex<State>>,
}

impl WebViewer {
    /// Starts serving on `addr` (e.g. `127.0.0.1:8080`; port 0 picks one).
    pub fn start(addr: &str) -> io::Result<Self> {
        let listener = TcpListener::bind(addr)?;
        let addr = listener.local_addr()?.to_string();
        let state = Arc::new(Mutex::new(State {
            png: imgio::encode_png_rgb(&RgbImage::new(480, 272, [16, 18, 24])),
            status: "{\"frame_id\":0}".into(),
        }));
        let shared = state.clone();
        std::thread::spawn(move || {
            for stream in listener.incoming().flatten() {
                let _ = serve(stream, &shared);
            }
        });
        Ok(WebViewer { addr, state })
    }

    /// The address it serves on.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }
}

fn serve(mut stream: TcpStream, state: &Mutex<State>) -> io::Result<()> {
    stream.set_read_timeout(Some(std::time::Duration::from_secs(2)))?;
    let mut line = String::new();
    BufReader::new(&stream).take_line(&mut line)?;
    let path = line.split_whitespace().nth(1).unwrap_or("/");
    let path = path.split('?').next().unwrap_or("/");
    let (status, kind, body): (&str, &str, Vec<u8>) = {
        let s = state
            .lock()
            .map_err(|_| io::Error::other("viewer state poisoned"))?;
        match path {
            "/" | "/index.html" => (
                "200 OK",
                "text/html; charset=utf-8",
                PAGE.as_bytes().to_vec(),
            ),
            "/screen.png" => ("200 OK", "image/png", s.png.clone()),
            "/status.json" => ("200 OK", "application/json", s.status.clone().into_bytes()),
            _ => ("404 Not Found", "text/plain", b"not found".to_vec()),
        }
    };
    write!(stream, "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n", body.len())?;
    stream.write_all(&body)
}

/// Reads one line, bounded, so a client cannot make the server buffer without limit.
trait TakeLine {
    fn take_line(self, line: &mut String) -> io::Result<usize>;
}

impl<R: BufRead> TakeLine for R {
    fn take_line(self, line: &mut String) -> io::Result<usize> {
        io::Read::take(self, 8192).read_line(line)
    }
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
    use std::io::Read;

    fn get(addr: &str, path: &str) -> (String, Vec<u8>) {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
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
    }
}
