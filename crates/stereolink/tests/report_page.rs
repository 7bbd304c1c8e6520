//! `stereolink report` on a folder of synthetic scenes: the page opens in
//! headless Chromium with every image loaded and the tables present, and one
//! scene's numbers agree with the library functions.

mod common;

use common::run_ok;

use std::path::Path;
use std::process::Command;

use stereolink_image::metrics::psnr_rgb;
use stereolink_image::Scene;
use stereolink_segment::segment;

#[test]
fn report_on_synthetic_scenes_opens_in_chromium() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    // The second scene's folder name holds HTML's special characters: the
    // page must show it as text, and its images must still load.
    for (seed, name) in [("1", "synth1"), ("2", "synth<2>&'\"")] {
        let s = data.join(name);
        run_ok(&[
            "synth",
            s.to_str().unwrap(),
            "--width",
            "128",
            "--height",
            "96",
            "--max-disp",
            "16",
            "--seed",
            seed,
        ]);
    }
    let out = dir.path().join("report");
    run_ok(&[
        "report",
        "--data",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        html.matches("<table>").count() >= 2 + 2 * 2,
        "tables missing"
    );
    assert!(html.contains("synth&lt;2&gt;&amp;'&quot;") && !html.contains("<2>"));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["scenes"].as_array().unwrap().len(), 2);

    // One scene's numbers against the library.
    let scene = Scene::load(data.join("synth1")).unwrap();
    let sr = &json["scenes"][0];
    assert_eq!(sr["name"], "synth1");
    let km = segment(&scene.left, &"kmeans".parse().unwrap(), 3, 1).unwrap();
    let psnr = psnr_rgb(&scene.left, &km.to_rgb()).unwrap().overall;
    assert!((sr["segmentation"]["kmeans"]["psnr_db"].as_f64().unwrap() - psnr).abs() < 1e-9);
    // Table IV's lossy columns: the original pair fitted to each method's
    // bytes. More bytes never give WebP less PSNR, and WebP beats JPEG.
    let mut lossy: Vec<(u64, f64, f64)> = sr["segmentation"]
        .as_object()
        .unwrap()
        .values()
        .map(|m| {
            let db = |codec: &str| m["lossy_psnr_db"][codec].as_f64().expect("the codec fits");
            (m["coded_bytes"].as_u64().unwrap(), db("webp"), db("jpeg"))
        })
        .collect();
    lossy.sort_by(|a, b| a.partial_cmp(b).unwrap());
    for w in lossy.windows(2) {
        assert!(
            w[1].1 >= w[0].1,
            "WebP PSNR fell with more bytes: {lossy:?}"
        );
    }
    assert!(
        lossy
            .iter()
            .all(|&(_, webp, jpeg)| webp > jpeg && jpeg > 15.0),
        "{lossy:?}"
    );
    let sgm_bad = sr["matching"]["original"]["sgm"]["bad1_nonocc"]
        .as_f64()
        .unwrap();
    assert!(sgm_bad < 10.0, "{sgm_bad}");

    let chromium = Path::new("/usr/bin/chromium");
    if !chromium.exists() {
        assert!(
            std::env::var("STEREOLINK_REQUIRE_CHROMIUM").as_deref() != Ok("1"),
            "chromium is required but absent"
        );
        eprintln!("/usr/bin/chromium is absent: skipping the browser check");
        return;
    }
    let profile = dir.path().join("profile");
    let dom = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
        ])
        .args([
            "--disable-component-update",
            "--disable-sync",
            "--allow-file-access-from-files",
            "--virtual-time-budget=5000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("file://{}", out.join("index.html").display()))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&dom.stdout);
    let attr = |name: &str| -> usize {
        let key = format!("{name}=\"");
        let start = dom
            .find(&key)
            .unwrap_or_else(|| panic!("{name} missing from the DOM"))
            + key.len();
        dom[start..].split('"').next().unwrap().parse().unwrap()
    };
    let (total, ok) = (attr("data-images-total"), attr("data-images-ok"));
    assert!(total >= 2 * 14, "only {total} images");
    assert_eq!(ok, total, "{ok} of {total} images loaded");
    assert!(dom.contains("<table>") || dom.contains("<tbody>"));
}
