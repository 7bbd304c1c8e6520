//! Where the screen goes: the Linux framebuffer, PNG snapshots, or the web
//! viewer ([`crate::web`]); chosen with a spec: `fb:/dev/fb0`, `png:DIR`,
//! `web:127.0.0.1:8080`.

use std::io;
use std::path::PathBuf;

use stereolink_image::{io as imgio, RgbImage};

use crate::screen::ScreenStatus;
use crate::web::WebViewer;

/// A place to show the screen.
pub trait Sink: Send {
    /// Shows one screen image with its status.
    fn show(&mut self, screen: &RgbImage, status: &ScreenStatus) -> io::Result<()>;
    /// A short description.
    fn describe(&self) -> String;
}

/// Framebuffer pixel formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// 16 bits: 5 red, 6 green, 5 blue, little-endian.
    Rgb565,
    /// 32 bits: blue, green, red, unused (little-endian XRGB8888).
    Xrgb8888,
}

impl PixelFormat {
    /// Bytes per pixel.
    pub fn bytes(self) -> usize {
        match self {
            PixelFormat::Rgb565 => 2,
            PixelFormat::Xrgb8888 => 4,
        }
    }
}

/// Packs `screen` into a framebuffer of `width`×`height` pixels whose rows
/// are `line_length` bytes apart (the kernel's stride, often more than
/// `width · bpp`); the screen is clipped to the framebuffer.
pub fn pack(
    screen: &RgbImage,
    format: PixelFormat,
    width: usize,
    height: usize,
    line_length: usize,
    out: &mut [u8],
) {
    let bpp = format.bytes();
    for y in 0..screen.height().min(height) {
        let Some(row_out) =
            out.get_mut(y * line_length..y * line_length + width.min(screen.width()) * bpp)
        else {
            break;
        };
        for (px, chunk) in screen.row(y).iter().zip(row_out.chunks_exact_mut(bpp)) {
            let [r, g, b] = *px;
            match format {
                PixelFormat::Rgb565 => {
                    let v = ((r as u16 >> 3) << 11) | ((g as u16 >> 2) << 5) | (b as u16 >> 3);
                    chunk.copy_from_slice(&v.to_le_bytes());
                }
                PixelFormat::Xrgb8888 => chunk.copy_from_slice(&[b, g, r, 0]),
            }
        }
    }
}

/// The Linux framebuffer (`/dev/fbN`), RGB565 or XRGB8888.
pub struct FramebufferSink {
    fb: framebuffer::Framebuffer,
    format: PixelFormat,
    buffer: Vec<u8>,
}

impl FramebufferSink {
    /// Opens a framebuffer device and reads its geometry.
    pub fn open(path: &str) -> io::Result<Self> {
        let fb = framebuffer::Framebuffer::new(path).map_err(|e| {
            io::Error::new(
                io::ErrorKind::NotFound,
                format!("cannot open framebuffer {path}: {e:?}"),
            )
        })?;
        let format = match fb.var_screen_info.bits_per_pixel {
            16 => PixelFormat::Rgb565,
            32 => PixelFormat::Xrgb8888,
            other => {
                return Err(io::Error::new(
                    io::ErrorKind::Unsupported,
                    format!("{path}: {other} bits per pixel is not supported"),
                ))
            }
        };
        let len = fb.fix_screen_info.line_length as usize * fb.var_screen_info.yres as usize;
        Ok(FramebufferSink {
            fb,
            format,
            buffer: vec![0; len],
        })
    }
}

impl Sink for FramebufferSink {
    fn show(&mut self, screen: &RgbImage, _status: &ScreenStatus) -> io::Result<()> {
        let v = &self.fb.var_screen_info;
        pack(
            screen,
            self.format,
            v.xres as usize,
            v.yres as usize,
            self.fb.fix_screen_info.line_length as usize,
            &mut self.buffer,
        );
        self.fb.write_frame(&self.buffer);
        Ok(())
    }

    fn describe(&self) -> String {
        format!("framebuffer {:?}", self.format)
    }
}

/// PNG snapshots: `screen-NNNNN.png` per frame and `screen.png` (the latest).
pub struct PngSink {
    dir: PathBuf,
}

impl PngSink {
    /// Writes into `dir` (created if needed).
    pub fn new(dir: impl Into<PathBuf>) -> io::Result<Self> {
        let dir = dir.into();
        std::fs::create_dir_all(&dir)?;
        Ok(PngSink { dir })
    }
}

impl Sink for PngSink {
    fn show(&mut self, screen: &RgbImage, status: &ScreenStatus) -> io::Result<()> {
        let to_io = |e: stereolink_image::Error| io::Error::other(e.to_string());
        imgio::write_rgb(
            self.dir.join(format!("screen-{:05}.png", status.frame_id)),
            screen,
        )
        .map_err(to_io)?;
        imgio::write_rgb(self.dir.join("screen.png"), screen).map_err(to_io)
    }

    fn describe(&self) -> String {
        format!("png:{}", self.dir.display())
    }
}

/// Opens a sink from its spec: `fb:/dev/fb0`, `png:DIR` or `web:ADDR:PORT`.
pub fn open_sink(spec: &str) -> io::Result<Box<dyn Sink>> {
    let bad = || {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("display {spec:?}: use fb:/dev/fb0, png:DIR or web:127.0.0.1:8080"),
        )
    };
    let (kind, arg) = spec.split_once(':').ok_or_else(bad)?;
    Ok(match kind {
        "fb" => Box::new(FramebufferSink::open(arg)?),
        "png" => Box::new(PngSink::new(arg)?),
        "web" => Box::new(WebViewer::start(arg)?),
        _ => return Err(bad()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file-backed buffer with the geometry of a 480x272 RGB565 TFT whose
    /// stride is padded to 512 pixels, and of an XRGB8888 one.
    #[test]
    fn packing_honours_format_and_stride() {
        let screen = RgbImage::from_fn(480, 272, |x, y| [(x % 256) as u8, (y % 256) as u8, 0xFF]);
        let dir = tempfile::tempdir().unwrap();
        for (format, line) in [
            (PixelFormat::Rgb565, 1024usize),
            (PixelFormat::Xrgb8888, 480 * 4),
        ] {
            let mut buf = vec![0xAAu8; line * 272];
            pack(&screen, format, 480, 272, line, &mut buf);
            let path = dir.path().join("fb");
            std::fs::write(&path, &buf).unwrap();
            let back = std::fs::read(&path).unwrap();
            let at = |x: usize, y: usize| &back[y * line + x * format.bytes()..];
            match format {
                PixelFormat::Rgb565 => {
                    let v = u16::from_le_bytes([at(200, 100)[0], at(200, 100)[1]]);
                    assert_eq!(
                        (v >> 11, (v >> 5) & 0x3F, v & 0x1F),
                        (200 >> 3, 100 >> 2, 0x1F)
                    );
                    assert_eq!(back[100 * line + 960], 0xAA, "padding untouched");
                }
                PixelFormat::Xrgb8888 => assert_eq!(&at(200, 100)[..4], &[0xFF, 100, 200, 0]),
            }
        }
    }

    #[test]
    fn png_sink_and_bad_specs() {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = open_sink(&format!("png:{}", dir.path().display())).unwrap();
        sink.show(
            &RgbImage::new(4, 4, [1, 2, 3]),
            &ScreenStatus {
                frame_id: 3,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(
            dir.path().join("screen-00003.png").is_file()
                && dir.path().join("screen.png").is_file()
        );
        assert!(open_sink("tv:1").is_err());
        assert!(open_sink("fb:/dev/does-not-exist").is_err());
    }
}
