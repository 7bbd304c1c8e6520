//! `stereolink report`: reruns the paper's experiments on a data folder and
//! writes an HTML page (`index.html`, images in `img/`) and `report.json`.
//!
//! Per scene: each segmentation method (the paper's five and the exact
//! multilevel Otsu) with PSNR (Table IV), coded size and reduction against the
//! original PNG files (Fig. 12), and time (Fig. 26); then WTA, line growing
//! and SGM on the original pair and on every segmented pair, scored against
//! the ground truth (bad > 1 px, non-occluded) with their depth-level counts
//! (Tables V and VI) and times (Fig. 27). The paper's figures stand beside
//! ours. The plane matcher (`planes`) runs on the original pair with the
//! segments of each input: the connected components of that method's left
//! labels, or the default mean shift over-segmentation for the original
//! pair; the headline says whether segmenting first helps it. Seeds are
//! fixed, so two runs give the same numbers (times aside).

pub mod paper;
pub mod svg;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use stereolink_codec::{container, Message, SegmentationKind, StereoFrame, View};
use stereolink_display::{anaglyph, Anaglyph};
use stereolink_image::{colormap, io, metrics, DisparityMap, LabelMap, RgbImage, Scene};
use stereolink_pipeline::planes::{left_segments, Segments};
use stereolink_segment::{segment, Method};
use stereolink_stereo::depth::{depth_levels, LevelSpec};
use stereolink_stereo::{compute_disparity, Algorithm, MatchSpec, Matcher};

/// Classes per method: k = 3 for k-means (the paper's), 3 levels per channel for thresholding.
pub const LEVELS: usize = 3;
/// Seed of every stochastic method.
pub const SEED: u64 = 1;

/// One segmentation of one scene.
#[derive(Clone, Debug, Serialize)]
pub struct SegResult {
    /// PSNR of the segmented left view against the original, dB.
    pub psnr_db: f64,
    /// The paper's PSNR for this scene and method.
    pub paper_psnr_db: Option<f64>,
    /// Bytes of the coded pair (StereoFrame message).
    pub coded_bytes: usize,
    /// Reduction against the original PNG files, percent.
    pub reduction_percent: f64,
    /// Segmentation time of both views, ms.
    pub time_ms: f64,
    /// Classes in the left view's palette.
    pub classes: usize,
}

/// One matcher on one input pair of one scene.
#[derive(Clone, Debug, Serialize)]
pub struct MatchResult {
    /// Bad > 1 px over non-occluded pixels, percent.
    pub bad1_nonocc: Option<f64>,
    /// Bad > 2 px over non-occluded pixels, percent.
    pub bad2_nonocc: Option<f64>,
    /// Depth levels (see `stereolink_stereo::depth::LevelSpec`).
    pub levels: usize,
    /// The paper's count (WTA: Table V, line growing: Table VI).
    pub paper_levels: Option<u32>,
    /// Matching time, ms.
    pub time_ms: f64,
}

/// Everything measured on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct SceneReport {
    /// Scene name.
    pub name: String,
    /// Width and height.
    pub size: (usize, usize),
    /// Disparities searched.
    pub ndisp: usize,
    /// Bytes of the original left and right files.
    pub original_bytes: u64,
    /// Per method.
    pub segmentation: BTreeMap<String, SegResult>,
    /// Per input ("original" or a method), per algorithm.
    pub matching: BTreeMap<String, BTreeMap<String, MatchResult>>,
}

/// The whole report.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Per scene.
    pub scenes: Vec<SceneReport>,
    /// Total run time, seconds.
    pub seconds: f64,
}

/// Methods in report order: the paper's five, then the exact optimum.
pub fn methods() -> Vec<Method> {
    ["meanshift", "kmeans", "pso", "dpso", "fodpso", "otsu"]
        .iter()
        .map(|m| m.parse().expect("known method"))
        .collect()
}

fn img_name(scene: &str, what: &str) -> String {
    format!("img/{scene}-{what}.png")
}

/// Computes one scene, writing its images under `out/img/`.
pub fn scene_report(scene: &Scene, dir: &Path, out: &Path) -> anyhow::Result<SceneReport> {
    let (w, h) = scene.left.dims();
    let ndisp = scene.calib.ndisp.clamp(2, w - 1);
    let original_bytes = ["left.png", "right.png", "im0.png", "im1.png"]
        .iter()
        .filter_map(|f| std::fs::metadata(dir.join(f)).ok())
        .map(|m| m.len())
        .sum::<u64>()
        .max(1);
    let save =
        |what: &str, img: &RgbImage| io::write_rgb(out.join(img_name(&scene.name, what)), img);
    save("left", &scene.left)?;
    save(
        "anaglyph",
        &anaglyph(&scene.left, &scene.right, Anaglyph::Dubois),
    )?;
    let mut pairs: Vec<(String, RgbImage, RgbImage)> =
        vec![("original".into(), scene.left.clone(), scene.right.clone())];
    // The plane matcher's segments per input.
    let mut segments: BTreeMap<String, LabelMap> = BTreeMap::new();
    segments.insert(
        "original".into(),
        left_segments(&scene.left, &Segments::OverSegmentation)?,
    );
    let mut segmentation = BTreeMap::new();
    for method in methods() {
        let t = Instant::now();
        let (sl, sr) = rayon::join(
            || segment(&scene.left, &method, LEVELS, SEED),
            || segment(&scene.right, &method, LEVELS, SEED),
        );
        let (sl, sr) = (sl?, sr?);
        let time_ms = t.elapsed().as_secs_f64() * 1e3;
        let (l, r) = (sl.to_rgb(), sr.to_rgb());
        let classes = sl.image.palette().len();
        segments.insert(method.name().to_string(), sl.image.labels().clone());
        let frame = StereoFrame {
            kind: SegmentationKind::from_name(method.name()).unwrap_or(SegmentationKind::None),
            levels: LEVELS as u8,
            params: String::new(),
            thresholds: None,
            calibration: None,
            left: View::Indexed(sl.image),
            right: View::Indexed(sr.image),
            planes: None,
        };
        let coded_bytes = container::encode(&Message::StereoFrame(Box::new(frame)), 0, 0).len();
        save(&format!("seg-{}", method.name()), &l)?;
        segmentation.insert(
            method.name().to_string(),
            SegResult {
                psnr_db: metrics::psnr_rgb(&scene.left, &l)?.overall,
                paper_psnr_db: paper::psnr(&scene.name, method.name()),
                coded_bytes,
                reduction_percent: metrics::reduction_percent(original_bytes as usize, coded_bytes),
                time_ms,
                classes,
            },
        );
        pairs.push((method.name().to_string(), l, r));
    }
    let mut matching = BTreeMap::new();
    let level_spec = LevelSpec::default();
    for (input, l, r) in &pairs {
        let mut per_algo = BTreeMap::new();
        for algo in Algorithm::ALL.into_iter().chain([Algorithm::Planes]) {
            let spec = MatchSpec::new(algo, 0, ndisp - 1)?;
            let t = Instant::now();
            let d = match algo {
                Algorithm::Planes => Matcher::new().compute_segmented(
                    &scene.left,
                    &scene.right,
                    Some(&segments[input]),
                    &spec,
                )?,
                _ => compute_disparity(l, r, &spec)?,
            };
            let time_ms = t.elapsed().as_secs_f64() * 1e3;
            let score = |th| {
                scene
                    .gt_left
                    .as_ref()
                    .and_then(|gt| metrics::bad_pixel_rate(&d, gt, scene.masks.nonocc.as_ref(), th))
            };
            let table: &[(&str, [u32; 6])] = match algo {
                Algorithm::Wta => &paper::TABLE_V,
                Algorithm::LineGrowing => &paper::TABLE_VI,
                Algorithm::Sgm | Algorithm::Planes => &[],
            };
            if input == "original" || input == "fodpso" {
                save(
                    &format!("disp-{input}-{}", algo.name()),
                    &colormap::colorize_with_bar(&d, 0.0, (ndisp - 1) as f32),
                )?;
            }
            if input == "original" && algo == Algorithm::Sgm {
                if let Some(gt) = &scene.gt_left {
                    save("error-sgm", &error_map(&d, gt))?;
                }
            }
            per_algo.insert(
                algo.name().to_string(),
                MatchResult {
                    bad1_nonocc: score(1.0),
                    bad2_nonocc: score(2.0),
                    levels: depth_levels(&d, &level_spec).levels.len(),
                    paper_levels: paper::levels(table, &scene.name, input),
                    time_ms,
                },
            );
        }
        matching.insert(input.clone(), per_algo);
    }
    Ok(SceneReport {
        name: scene.name.clone(),
        size: (w, h),
        ndisp,
        original_bytes,
        segmentation,
        matching,
    })
}

/// Green where |d − gt| ≤ 1, red where larger, black where the ground truth is unknown.
fn error_map(d: &DisparityMap, gt: &DisparityMap) -> RgbImage {
    RgbImage::from_fn(d.width(), d.height(), |x, y| {
        let (e, g) = (d.get(x, y), gt.get(x, y));
        if !g.is_finite() {
            [0, 0, 0]
        } else if e.is_finite() && (e - g).abs() <= 1.0 {
            [40, 160, 60]
        } else {
            [220, 40, 40]
        }
    })
}

/// Runs the report over the scene folders and writes it into `out`.
pub fn run(dirs: &[PathBuf], out: &Path, progress: &dyn Fn(&str)) -> anyhow::Result<Report> {
    let start = Instant::now();
    std::fs::create_dir_all(out.join("img"))
        .with_context(|| format!("cannot create {}", out.display()))?;
    let mut scenes = Vec::new();
    for dir in dirs {
        let scene = Scene::load(dir)?;
        progress(&scene.name);
        scenes
            .push(scene_report(&scene, dir, out).with_context(|| format!("scene {}", scene.name))?);
    }
    let report = Report {
        scenes,
        seconds: start.elapsed().as_secs_f64(),
    };
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    std::fs::write(out.join("index.html"), html(&report))?;
    Ok(report)
}

/// The headline on the plane matcher: does any segmentation's planes beat
/// the over-segmentation of the original pair (mean bad > 1 px)?
fn planes_headline(inputs: &[String], bad: impl Fn(&str) -> Option<f64>) -> String {
    let Some(original) = bad("original") else {
        return String::new();
    };
    let best = inputs
        .iter()
        .skip(1)
        .filter_map(|i| bad(i).map(|b| (i, b)))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    let verdict = match best {
        Some((i, b)) if b < original => format!(
            "yes: planes over the {i} segments give {b:.2} % bad &gt; 1 px against {original:.2} % over the over-segmented original"
        ),
        Some((i, b)) => format!(
            "no: the best segmentation ({i}) gives {b:.2} % bad &gt; 1 px against {original:.2} % over the over-segmented original"
        ),
        None => format!("no segmented input was scored (original {original:.2} %)"),
    };
    format!("<p><b>Does segmenting first help when the segments carry planes?</b> {verdict}.</p>")
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let v: Vec<f64> = v.collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn f(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.digits$}"))
}

/// A table whose best value per numeric column is marked (`lower` says which way is better per column).
fn table(head: &[&str], rows: &[Vec<String>], lower: &[Option<bool>]) -> String {
    let mut best: Vec<Option<f64>> = vec![None; head.len()];
    for (c, dir) in lower.iter().enumerate() {
        if let Some(low) = dir {
            best[c] = rows
                .iter()
                .filter_map(|r| r.get(c).and_then(|v| v.parse::<f64>().ok()))
                .fold(None, |acc, v| {
                    Some(acc.map_or(v, |a: f64| {
                        if (*low && v < a) || (!*low && v > a) {
                            v
                        } else {
                            a
                        }
                    }))
                });
        }
    }
    let mut s = String::from("<table><tr>");
    for h in head {
        s += &format!("<th>{h}</th>");
    }
    s += "</tr>";
    for r in rows {
        s += "<tr>";
        for (c, v) in r.iter().enumerate() {
            let is_best = best
                .get(c)
                .copied()
                .flatten()
                .is_some_and(|b| v.parse::<f64>().ok() == Some(b));
            s += &if is_best {
                format!("<td class=best>{v}</td>")
            } else {
                format!("<td>{v}</td>")
            };
        }
        s += "</tr>";
    }
    s + "</table>"
}

fn html(r: &Report) -> String {
    let names: Vec<String> = methods().iter().map(|m| m.name().to_string()).collect();
    let seg = |m: &str, f: fn(&SegResult) -> f64| {
        mean(r.scenes.iter().filter_map(|s| s.segmentation.get(m)).map(f))
    };
    let paper_psnr = |m: &str| mean(r.scenes.iter().filter_map(|s| paper::psnr(&s.name, m)));
    let mut page = String::from(
        "<!doctype html><html><head><meta charset=utf-8><title>stereolink report</title><style>\
         body{font-family:sans-serif;margin:24px;max-width:1400px;color:#222}table{border-collapse:collapse;margin:8px 0 20px}\
         td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}th{background:#f0f0f0}td.best{font-weight:bold;background:#e6f4e6}\
         .imgs img{height:150px;margin:2px;image-rendering:pixelated}.imgs figure{display:inline-block;margin:4px;text-align:center;font-size:12px}\
         </style></head><body>",
    );
    page += &format!(
        "<h1>stereolink: the paper's experiments, rerun</h1><p>{} scenes in {:.0} s. Segmentation: {LEVELS} classes (k-means k = {LEVELS}; \
         {LEVELS} levels per channel for the thresholding methods), seed {SEED}. Matching scored against the ground truth: bad &gt; 1 px over \
         non-occluded pixels, dense output (invalid counts as bad). Best value per column in bold.</p>",
        r.scenes.len(),
        r.seconds
    );
    // Summary: Table IV and Fig. 12.
    let rows: Vec<Vec<String>> = names
        .iter()
        .map(|m| {
            let ci = paper::reduction_ci(m);
            let ours = seg(m, |s| s.psnr_db);
            // Compare like with like: our mean over the scenes the paper reports.
            let ours_common = mean(r.scenes.iter().filter_map(|s| {
                s.segmentation
                    .get(m)
                    .filter(|x| x.paper_psnr_db.is_some())
                    .map(|x| x.psnr_db)
            }));
            let theirs = paper_psnr(m);
            vec![
                m.clone(),
                f(ours, 2),
                f(ours_common, 2),
                f(theirs, 2),
                f(ours_common.zip(theirs).map(|(a, b)| a - b), 2),
                f(seg(m, |s| s.reduction_percent), 2),
                ci.map_or("–".into(), |(a, b)| format!("{a}–{b}")),
                f(seg(m, |s| s.coded_bytes as f64), 0),
                f(seg(m, |s| s.time_ms), 1),
            ]
        })
        .collect();
    page += "<h2>Segmentation (Table IV, Fig. 12, Fig. 26), means over the scenes</h2>";
    page += &table(
        &[
            "method",
            "PSNR dB",
            "PSNR on the paper's scenes",
            "paper PSNR",
            "difference",
            "reduction %",
            "paper 95 % CI",
            "coded pair B",
            "time ms",
        ],
        &rows,
        &[
            None,
            Some(false),
            Some(false),
            None,
            None,
            Some(false),
            None,
            Some(true),
            Some(true),
        ],
    );
    let cats: Vec<String> = names.clone();
    page += &svg::bars(
        "PSNR of the segmented left view (dB)",
        "dB",
        &cats,
        &[
            (
                "ours".into(),
                names.iter().map(|m| seg(m, |s| s.psnr_db)).collect(),
            ),
            (
                "paper".into(),
                names.iter().map(|m| paper_psnr(m)).collect(),
            ),
        ],
    );
    page += &svg::bars(
        "Size reduction against the original PNG pair (%)",
        "%",
        &cats,
        &[
            (
                "ours".into(),
                names
                    .iter()
                    .map(|m| seg(m, |s| s.reduction_percent))
                    .collect(),
            ),
            (
                "paper CI low".into(),
                names
                    .iter()
                    .map(|m| paper::reduction_ci(m).map(|c| c.0))
                    .collect(),
            ),
            (
                "paper CI high".into(),
                names
                    .iter()
                    .map(|m| paper::reduction_ci(m).map(|c| c.1))
                    .collect(),
            ),
        ],
    );
    page += &svg::bars(
        "Segmentation time of both views (ms)",
        "ms",
        &cats,
        &[(
            "ours".into(),
            names.iter().map(|m| seg(m, |s| s.time_ms)).collect(),
        )],
    );
    // Matching summary.
    let inputs: Vec<String> = std::iter::once("original".to_string())
        .chain(names.iter().cloned())
        .collect();
    let algos = ["wta", "lg", "sgm", "planes"];
    let m = |input: &str, algo: &str, f: fn(&MatchResult) -> Option<f64>| {
        mean(
            r.scenes
                .iter()
                .filter_map(|s| s.matching.get(input).and_then(|a| a.get(algo)))
                .filter_map(f),
        )
    };
    let rows: Vec<Vec<String>> = inputs
        .iter()
        .map(|i| {
            let mut row = vec![i.clone()];
            for a in algos {
                row.push(f(m(i, a, |x| x.bad1_nonocc), 2));
            }
            for a in algos {
                row.push(f(m(i, a, |x| Some(x.levels as f64)), 1));
            }
            for a in algos {
                row.push(f(m(i, a, |x| Some(x.time_ms)), 1));
            }
            row
        })
        .collect();
    page += "<h2>Matching (Tables V and VI, Fig. 27), means over the scenes</h2><p>Does segmenting first help matching? \
             Compare each segmented input's bad-pixel rate with the original pair's. The planes column matches the original \
             pair with a plane per segment of that input (the original: a mean shift over-segmentation).</p>";
    page += &planes_headline(&inputs, |i| m(i, "planes", |x| x.bad1_nonocc));
    page += &table(
        &[
            "input",
            "WTA bad1 %",
            "LG bad1 %",
            "SGM bad1 %",
            "Planes bad1 %",
            "WTA levels",
            "LG levels",
            "SGM levels",
            "Planes levels",
            "WTA ms",
            "LG ms",
            "SGM ms",
            "Planes ms",
        ],
        &rows,
        &[
            None,
            Some(true),
            Some(true),
            Some(true),
            Some(true),
            None,
            None,
            None,
            None,
            Some(true),
            Some(true),
            Some(true),
            Some(true),
        ],
    );
    page += &svg::scatter(
        "Accuracy against time, per scene and input",
        "matching time (ms)",
        "bad > 1 px (%)",
        &algos
            .iter()
            .map(|a| {
                let pts = r
                    .scenes
                    .iter()
                    .flat_map(|s| {
                        s.matching
                            .values()
                            .filter_map(|per| per.get(*a))
                            .filter_map(|x| x.bad1_nonocc.map(|b| (x.time_ms, b)))
                    })
                    .collect();
                (a.to_string(), pts)
            })
            .collect::<Vec<_>>(),
    );
    // Per scene.
    for s in &r.scenes {
        page += &format!(
            "<h2 id=\"{0}\">{0} ({1}x{2}, {3} disparities)</h2><div class=imgs>",
            s.name, s.size.0, s.size.1, s.ndisp
        );
        let fig = |what: &str, cap: &str| {
            format!(
                "<figure><img src=\"{}\" alt=\"{cap}\"><figcaption>{cap}</figcaption></figure>",
                img_name(&s.name, what)
            )
        };
        page += &fig("left", "left view");
        page += &fig("anaglyph", "anaglyph (Dubois)");
        for n in &names {
            page += &fig(&format!("seg-{n}"), n);
        }
        page += "<br>";
        for input in ["original", "fodpso"] {
            for a in algos {
                page += &fig(&format!("disp-{input}-{a}"), &format!("{a} on {input}"));
            }
        }
        if s.matching["original"]["sgm"].bad1_nonocc.is_some() {
            page += &fig("error-sgm", "SGM errors (red: > 1 px)");
        }
        page += "</div>";
        let rows: Vec<Vec<String>> = names
            .iter()
            .map(|n| {
                let x = &s.segmentation[n];
                vec![
                    n.clone(),
                    format!("{:.2}", x.psnr_db),
                    f(x.paper_psnr_db, 2),
                    format!("{:.2}", x.reduction_percent),
                    x.coded_bytes.to_string(),
                    x.classes.to_string(),
                    format!("{:.1}", x.time_ms),
                ]
            })
            .collect();
        page += &table(
            &[
                "method",
                "PSNR dB",
                "paper",
                "reduction %",
                "bytes",
                "classes",
                "ms",
            ],
            &rows,
            &[
                None,
                Some(false),
                None,
                Some(false),
                Some(true),
                None,
                Some(true),
            ],
        );
        let rows: Vec<Vec<String>> = inputs
            .iter()
            .map(|i| {
                let mut row = vec![i.clone()];
                for a in algos {
                    let x = &s.matching[i][a];
                    row.push(f(x.bad1_nonocc, 2));
                    row.push(format!(
                        "{}{}",
                        x.levels,
                        x.paper_levels.map_or(String::new(), |p| format!(" ({p})"))
                    ));
                }
                row
            })
            .collect();
        page += &table(
            &[
                "input",
                "WTA bad1 %",
                "WTA levels (paper)",
                "LG bad1 %",
                "LG levels (paper)",
                "SGM bad1 %",
                "SGM levels",
                "Planes bad1 %",
                "Planes levels",
            ],
            &rows,
            &[
                None,
                Some(true),
                None,
                Some(true),
                None,
                Some(true),
                None,
                Some(true),
                None,
            ],
        );
    }
    page += "<script>window.addEventListener('load',()=>{const im=[...document.images];\
             document.body.dataset.imagesTotal=im.length;\
             document.body.dataset.imagesOk=im.filter(i=>i.complete&&i.naturalWidth>0).length;});</script></body></html>";
    page
}
