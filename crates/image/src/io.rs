//! Reading and writing PNG, PPM and PGM files (and reading JPEG) through the
//! `image` crate.
//!
//! Decoding is bounded: images above [`MAX_PIXELS`] are refused before their
//! pixels are allocated, so a forged header cannot exhaust memory.

use std::io::Cursor;
use std::path::Path;

use image::{DynamicImage, ImageFormat, ImageReader, Limits};

use crate::{Error, GrayImage, Plane, Result, RgbImage};

/// Largest image accepted by the readers: 64 Mpixel.
pub const MAX_PIXELS: usize = 1 << 26;

fn decode(path: &Path, bytes: &[u8]) -> Result<DynamicImage> {
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    if reader.format().is_none() {
        return Err(Error::decode(path, "not a PNG, JPEG, PPM or PGM file"));
    }
    let mut limits = Limits::default();
    limits.max_alloc = Some(MAX_PIXELS as u64 * 8);
    reader.limits(limits.clone());
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| Error::decode(path, e.to_string()))?;
    let (w, h) = (w as usize, h as usize);
    if w.saturating_mul(h) > MAX_PIXELS {
        return Err(Error::TooLarge {
            what: path.display().to_string(),
            width: w,
            height: h,
            max_pixels: MAX_PIXELS,
        });
    }
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    reader.limits(limits);
    reader
        .decode()
        .map_err(|e| Error::decode(path, e.to_string()))
}

fn read_dynamic(path: &Path) -> Result<DynamicImage> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode(path, &bytes)
}

/// Decodes an image held in memory as RGB (gray is replicated, alpha dropped).
pub fn decode_rgb(bytes: &[u8]) -> Result<RgbImage> {
    Ok(rgb_from_dynamic(decode(Path::new("<memory>"), bytes)?))
}

/// Reads a PNG, PPM or PGM file as RGB (gray is replicated, alpha dropped).
pub fn read_rgb(path: impl AsRef<Path>) -> Result<RgbImage> {
    Ok(rgb_from_dynamic(read_dynamic(path.as_ref())?))
}

/// Reads a PNG, PPM or PGM file as 8-bit gray (colour is converted with
/// [`crate::color::rgb_to_gray`]; 16-bit samples keep their high byte).
pub fn read_gray(path: impl AsRef<Path>) -> Result<GrayImage> {
    let img = read_dynamic(path.as_ref())?;
    Ok(match img {
        DynamicImage::ImageLuma8(g) => {
            let (w, h) = (g.width() as usize, g.height() as usize);
            Plane::from_vec(w, h, g.into_raw()).expect("buffer size matches dimensions")
        }
        other if !other.color().has_color() => {
            let g = other.to_luma8();
            let (w, h) = (g.width() as usize, g.height() as usize);
            Plane::from_vec(w, h, g.into_raw()).expect("buffer size matches dimensions")
        }
        other => crate::color::rgb_to_gray(&rgb_from_dynamic(other)),
    })
}

fn rgb_from_dynamic(img: DynamicImage) -> RgbImage {
    let rgb = img.to_rgb8();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let data = rgb
        .into_raw()
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Plane::from_vec(w, h, data).expect("buffer size matches dimensions")
}

fn format_for(path: &Path) -> Result<ImageFormat> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => Ok(ImageFormat::Png),
        Some("ppm" | "pgm" | "pnm") => Ok(ImageFormat::Pnm),
        _ => Err(Error::Encode {
            path: path.into(),
            reason: "unknown extension; use .png, .ppm or .pgm".into(),
        }),
    }
}

fn save(path: &Path, img: DynamicImage) -> Result<()> {
    let format = format_for(path)?;
    let mut out = Vec::new();
    img.write_to(&mut Cursor::new(&mut out), format)
        .map_err(|e| Error::Encode {
            path: path.into(),
            reason: e.to_string(),
        })?;
    std::fs::write(path, out).map_err(|e| Error::io(path, e))
}

/// Encodes an RGB image as PNG bytes.
pub fn encode_png_rgb(img: &RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    to_dynamic_rgb(img)
        .write_to(&mut Cursor::new(&mut out), ImageFormat::Png)
        .expect("PNG encoding into memory cannot fail");
    out
}

fn to_dynamic_rgb(img: &RgbImage) -> DynamicImage {
    let raw: Vec<u8> = img.as_slice().iter().flatten().copied().collect();
    DynamicImage::ImageRgb8(
        image::RgbImage::from_raw(img.width() as u32, img.height() as u32, raw)
            .expect("buffer size matches dimensions"),
    )
}

/// Writes an RGB image; the format follows the extension (`.png`, `.ppm`).
pub fn write_rgb(path: impl AsRef<Path>, img: &RgbImage) -> Result<()> {
    save(path.as_ref(), to_dynamic_rgb(img))
}

/// Writes a gray image; the format follows the extension (`.png`, `.pgm`).
pub fn write_gray(path: impl AsRef<Path>, img: &GrayImage) -> Result<()> {
    let buf = image::GrayImage::from_raw(
        img.width() as u32,
        img.height() as u32,
        img.as_slice().to_vec(),
    )
    .expect("buffer size matches dimensions");
    save(path.as_ref(), DynamicImage::ImageLuma8(buf))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> RgbImage {
        Plane::from_fn(5, 3, |x, y| [x as u8 * 40, y as u8 * 70, 200])
    }

    #[test]
    fn png_and_ppm_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["a.png", "a.ppm"] {
            let p = dir.path().join(name);
            write_rgb(&p, &sample()).unwrap();
            assert_eq!(read_rgb(&p).unwrap(), sample());
        }
        let g = crate::color::rgb_to_gray(&sample());
        for name in ["g.png", "g.pgm"] {
            let p = dir.path().join(name);
            write_gray(&p, &g).unwrap();
            assert_eq!(read_gray(&p).unwrap(), g);
        }
    }

    #[test]
    fn truncated_and_garbage_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        write_rgb(&p, &sample()).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let err = read_rgb(&p).unwrap_err().to_string();
        assert!(err.contains("a.png"), "{err}");
        std::fs::write(&p, b"hello world").unwrap();
        assert!(matches!(read_rgb(&p), Err(Error::Decode { .. })));
        assert!(matches!(
            read_rgb(dir.path().join("missing.png")),
            Err(Error::Io { .. })
        ));
    }

    #[test]
    fn huge_declared_size_is_refused_without_allocating() {
        let forged = b"P6\n100000 100000\n255\n\x00\x00\x00";
        assert!(decode_rgb(forged).is_err());
    }

    #[test]
    fn unknown_extension_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        assert!(write_rgb(dir.path().join("a.bmp"), &sample()).is_err());
    }
}
