//! The web viewer end to end in headless Chromium: the page loads, fetches
//! the screen image, and the screenshot shows the screen's colours.
//!
//! Skipped (with a note) when /usr/bin/chromium is absent, unless
//! `STEREOLINK_REQUIRE_CHROMIUM=1`, as CI sets after installing it.

use std::path::Path;
use std::process::Command;

use stereolink_display::web::WebViewer;
use stereolink_display::{Screen, ScreenStatus, Sink};
use stereolink_image::{io, DisparityMap, RgbImage};

const CHROMIUM: &str = "/usr/bin/chromium";

#[test]
fn viewer_page_shows_the_screen_in_chromium() {
    if !Path::new(CHROMIUM).exists() {
        assert!(
            std::env::var("STEREOLINK_REQUIRE_CHROMIUM").as_deref() != Ok("1"),
            "chromium is required but absent"
        );
        eprintln!("{CHROMIUM} is absent: skipping the browser test");
        return;
    }
    let mut viewer = WebViewer::start("127.0.0.1:0").unwrap();
    let mut screen = Screen::new();
    let view = RgbImage::new(200, 150, [0, 255, 0]);
    let disp = DisparityMap::new(200, 150, 5.0);
    let status = ScreenStatus {
        frame_id: 1,
        distance_m: Some(0.75),
        message: "BROWSER TEST".into(),
        ..Default::default()
    };
    let img = screen.render(&view, &disp, 0.0, 10.0, &status).clone();
    viewer.show(&img, &status).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("shot.png");
    let out = Command::new(CHROMIUM)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            "--virtual-time-budget=3000",
            "--window-size=1100,800",
        ])
        .arg(format!(
            "--user-data-dir={}",
            dir.path().join("profile").display()
        ))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(viewer.url())
        .output()
        .unwrap();
    assert!(
        shot.is_file(),
        "no screenshot: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let png = io::read_rgb(&shot).unwrap();
    let green = png
        .as_slice()
        .iter()
        .filter(|p| p[1] > 200 && p[0] < 60 && p[2] < 60)
        .count();
    // The 3-D panel (green) fills about 236x177 screen pixels, shown at 2x.
    assert!(
        green > 50_000,
        "only {green} green pixels: the screen image did not load"
    );
    let page_background = png.get(5, 5);
    assert!(
        page_background[0] < 40 && page_background[2] < 40,
        "{page_background:?}"
    );
}
