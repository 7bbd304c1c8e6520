//! Prints the chessboard corners of images as one JSON object.
//!
//! ```sh
//! cargo run --release -p stereolink-calib --example corners -- --board 9x6 left01.jpg left02.jpg
//! ```
//!
//! Output: `{ "files": { "<path>": [[x, y], ...] or null }, "ms_per_image": t }`,
//! with `t` the mean detection time (reading excluded) on one thread. Why a
//! board was not found goes to stderr, one line per image.

use std::collections::BTreeMap;
use std::time::Instant;

use stereolink_calib::chessboard::{find_chessboard_with, BoardSize, ChessboardOptions};

fn main() {
    let mut args = std::env::args().skip(1);
    let mut board = BoardSize::new(9, 6);
    let mut options = ChessboardOptions::default();
    let mut files = Vec::new();
    let usage = |e: String| -> ! {
        eprintln!("corners: {e}");
        std::process::exit(2)
    };
    while let Some(arg) = args.next() {
        if arg == "--board" {
            board = args
                .next()
                .unwrap_or_default()
                .parse()
                .unwrap_or_else(|e| usage(e));
        } else if arg == "--subpix-sigma" {
            let value = args.next().unwrap_or_default();
            options.subpix.sigma = value
                .parse()
                .unwrap_or_else(|_| usage(format!("--subpix-sigma {value:?} is not a number")));
        } else {
            files.push(arg);
        }
    }
    if files.is_empty() {
        eprintln!("usage: corners [--board COLSxROWS] [--subpix-sigma PX] FILE...");
        std::process::exit(2);
    }
    let mut out = BTreeMap::new();
    let mut seconds = 0.0;
    for file in &files {
        let image = match stereolink_image::io::read_gray(file) {
            Ok(image) => image,
            Err(e) => {
                eprintln!("corners: {e}");
                std::process::exit(1)
            }
        };
        let start = Instant::now();
        let found = find_chessboard_with(&image, board, &options);
        seconds += start.elapsed().as_secs_f64();
        let corners = match found {
            Ok(corners) => Some(corners.iter().map(|p| [p.x, p.y]).collect::<Vec<_>>()),
            Err(e) => {
                eprintln!("{file}: {e}");
                None
            }
        };
        out.insert(file.clone(), corners);
    }
    let report = serde_json::json!({
        "files": out,
        "ms_per_image": 1000.0 * seconds / files.len() as f64,
    });
    println!("{report}");
}
