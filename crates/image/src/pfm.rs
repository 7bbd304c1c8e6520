//! Portable Float Map (PFM) reading and writing, the Middlebury 2014 format
//! for disparity maps.
//!
//! Layout: a header line `Pf` (one channel) or `PF` (three), a line
//! `width height`, a line with the scale (negative = little-endian, its
//! magnitude is ignored here), then `f32` samples, rows **bottom to top**.
//! `inf` marks unknown disparity. A `PF` file is read as its first channel.
//!
//! The reader checks the declared size against the bytes actually present
//! before allocating, so a forged header cannot cause a huge allocation.

use std::path::Path;

use crate::{DisparityMap, Error, Plane, Result};

/// Parses PFM bytes into a disparity map (top-to-bottom rows).
pub fn decode(bytes: &[u8]) -> Result<DisparityMap> {
    decode_named(Path::new("<memory>"), bytes)
}

fn decode_named(path: &Path, bytes: &[u8]) -> Result<DisparityMap> {
    let bad = |reason: &str| Error::decode(path, format!("bad PFM: {reason}"));
    let mut fields = Vec::with_capacity(4);
    let mut pos = 0;
    // Four whitespace-separated header tokens, the last followed by exactly one whitespace byte.
    while fields.len() < 4 {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 32 {
            pos += 1;
        }
        if start == pos {
            return Err(bad("truncated header"));
        }
        fields
            .push(std::str::from_utf8(&bytes[start..pos]).map_err(|_| bad("header is not text"))?);
        if pos >= bytes.len() || !bytes[pos].is_ascii_whitespace() {
            return Err(bad("truncated or overlong header field"));
        }
    }
    pos += 1;
    let channels = match fields[0] {
        "Pf" => 1,
        "PF" => 3,
        other => return Err(bad(&format!("magic {other:?} is neither Pf nor PF"))),
    };
    let width: usize = fields[1]
        .parse()
        .map_err(|_| bad("width is not a number"))?;
    let height: usize = fields[2]
        .parse()
        .map_err(|_| bad("height is not a number"))?;
    let scale: f32 = fields[3]
        .parse()
        .map_err(|_| bad("scale is not a number"))?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(bad("scale must be a non-zero number"));
    }
    let little = scale < 0.0;
    let needed = width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(4 * channels))
        .ok_or_else(|| bad("dimensions overflow"))?;
    let body = &bytes[pos..];
    if body.len() < needed {
        return Err(bad(&format!(
            "{width}x{height} needs {needed} bytes of samples, found {}",
            body.len()
        )));
    }
    let mut data = vec![0f32; width * height];
    for (row_in_file, chunk) in body[..needed]
        .chunks_exact((width * 4 * channels).max(1))
        .enumerate()
    {
        let y = height - 1 - row_in_file;
        for x in 0..width {
            let b: [u8; 4] = chunk[x * 4 * channels..x * 4 * channels + 4]
                .try_into()
                .unwrap();
            data[y * width + x] = if little {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
        }
    }
    Plane::from_vec(width, height, data)
}

/// Serialises a disparity map as little-endian `Pf` bytes (scale −1).
pub fn encode(map: &DisparityMap) -> Vec<u8> {
    let header = format!("Pf\n{} {}\n-1\n", map.width(), map.height());
    let mut out = Vec::with_capacity(header.len() + map.len() * 4);
    out.extend_from_slice(header.as_bytes());
    for y in (0..map.height()).rev() {
        for v in map.row(y) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Reads a PFM file.
pub fn read(path: impl AsRef<Path>) -> Result<DisparityMap> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_named(path, &bytes)
}

/// Writes a PFM file (little-endian, one channel).
pub fn write(path: impl AsRef<Path>, map: &DisparityMap) -> Result<()> {
    let path = path.as_ref();
    std::fs::write(path, encode(map)).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn rows_are_stored_bottom_to_top() {
        let map = Plane::from_vec(2, 2, vec![1.0f32, 2.0, 3.0, f32::INFINITY]).unwrap();
        let bytes = encode(&map);
        let body = &bytes[bytes.len() - 16..];
        assert_eq!(f32::from_le_bytes(body[0..4].try_into().unwrap()), 3.0);
        assert_eq!(f32::from_le_bytes(body[8..12].try_into().unwrap()), 1.0);
        assert_eq!(decode(&bytes).unwrap(), map);
    }

    #[test]
    fn big_endian_and_three_channels() {
        let mut bytes = b"PF\n1 1\n1.0\n".to_vec();
        for v in [7.5f32, 1.0, 2.0] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        assert_eq!(decode(&bytes).unwrap().get(0, 0), 7.5);
    }

    #[test]
    fn malformed_headers_are_errors() {
        for bad in [
            &b""[..],
            b"P6\n1 1\n-1\n\0\0\0\0",
            b"Pf\n1 1\n0\n\0\0\0\0",
            b"Pf\nx 1\n-1\n\0\0\0\0",
            b"Pf\n2 2\n-1\n\0\0\0\0",
            b"Pf\n4000000000 4000000000\n-1\n",
            b"Pf\n18446744073709551615 2\n-1\n",
        ] {
            assert!(decode(bad).is_err(), "{:?}", String::from_utf8_lossy(bad));
        }
    }

    proptest! {
        #[test]
        fn round_trip_is_bit_exact(w in 0usize..9, h in 0usize..9, seed in any::<u64>()) {
            let mut s = seed;
            let map = Plane::from_fn(w, h, |_, _| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                f32::from_bits((s >> 32) as u32)
            });
            let back = decode(&encode(&map)).unwrap();
            let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            prop_assert_eq!(back.dims(), map.dims());
            prop_assert_eq!(bits(&back), bits(&map));
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = decode(&bytes);
        }
    }
}
