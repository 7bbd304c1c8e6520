//! Golden XBee API frames built by Digi's `digi-xbee` Python library
//! (`tests/golden/make_xbee_vectors.py`): each parses as exactly one frame
//! and re-encodes to the same bytes, in API mode 1 and 2.

use stereolink_link::xbee::{ApiMode, Parser};

#[test]
fn digi_xbee_vectors_parse_and_re_encode() {
    let text = include_str!("golden/xbee_vectors.txt");
    let mut n = 0;
    for line in text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
    {
        let mut parts = line.split_whitespace();
        let (name, mode, hex) = (
            parts.next().unwrap(),
            parts.next().unwrap(),
            parts.next().unwrap(),
        );
        let bytes: Vec<u8> = (0..hex.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
            .collect();
        let mode = if mode == "2" {
            ApiMode::Escaped
        } else {
            ApiMode::Plain
        };
        let mut p = Parser::new(mode);
        let frames: Vec<_> = bytes.iter().filter_map(|&b| p.push(b)).collect();
        assert_eq!(frames.len(), 1, "{name}: {frames:?}");
        let frame = frames
            .into_iter()
            .next()
            .unwrap()
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(frame.encode(mode), bytes, "{name} re-encodes differently");
        n += 1;
    }
    assert_eq!(n, 22);
}
