//! The report's HTML page: the summary tables and charts against the
//! paper's figures, then each scene's images and tables. Rendering only:
//! every number comes from the [`Report`] that `report` computed.
//!
//! The page is written with `maud`'s templates, which escape every value
//! they insert (scene names come from folder names); the charts come from
//! [`svg`], which escapes its own text.

use maud::{html, Markup, PreEscaped, DOCTYPE};

use super::{
    img_name, methods, paper, svg, MatchResult, Report, SceneReport, SegResult, LEVELS, SEED,
};

/// The page's style sheet.
const STYLE: &str = "body{font-family:sans-serif;margin:24px;max-width:1400px;color:#222}\
table{border-collapse:collapse;margin:8px 0 20px}\
td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}th{background:#f0f0f0}\
td.best{font-weight:bold;background:#e6f4e6}\
.imgs img{height:150px;margin:2px;image-rendering:pixelated}\
.imgs figure{display:inline-block;margin:4px;text-align:center;font-size:12px}";

/// Marks the page once its images have loaded, with how many did (the
/// report's browser test reads it).
const IMAGES_LOADED: &str = "window.addEventListener('load',()=>{const im=[...document.images];\
document.body.dataset.imagesTotal=im.length;\
document.body.dataset.imagesOk=im.filter(i=>i.complete&&i.naturalWidth>0).length;});";

/// The matchers, in the tables' order.
const ALGOS: [&str; 4] = ["wta", "lg", "sgm", "planes"];

/// The headline on the plane matcher: does any segmentation's planes beat
/// the over-segmentation of the original pair (mean bad > 1 px)?
fn planes_headline(inputs: &[String], bad: impl Fn(&str) -> Option<f64>) -> Markup {
    let Some(original) = bad("original") else {
        return html! {};
    };
    let best = inputs
        .iter()
        .skip(1)
        .filter_map(|i| bad(i).map(|b| (i, b)))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    let verdict = match best {
        Some((i, b)) if b < original => format!(
            "yes: planes over the {i} segments give {b:.2} % bad > 1 px against {original:.2} % over the over-segmented original"
        ),
        Some((i, b)) => format!(
            "no: the best segmentation ({i}) gives {b:.2} % bad > 1 px against {original:.2} % over the over-segmented original"
        ),
        None => format!("no segmented input was scored (original {original:.2} %)"),
    };
    html! { p { b { "Does segmenting first help when the segments carry planes?" } " " (verdict) "." } }
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let v: Vec<f64> = v.collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn f(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.digits$}"))
}

/// A table whose best value per numeric column is marked (`lower` says which way is better per column).
fn table(head: &[&str], rows: &[Vec<String>], lower: &[Option<bool>]) -> Markup {
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
    let is_best = |c: usize, v: &str| {
        best.get(c)
            .copied()
            .flatten()
            .is_some_and(|b| v.parse::<f64>().ok() == Some(b))
    };
    html! {
        table {
            tr { @for h in head { th { (h) } } }
            @for r in rows {
                tr {
                    @for (c, v) in r.iter().enumerate() {
                        @if is_best(c, v) { td.best { (v) } } @else { td { (v) } }
                    }
                }
            }
        }
    }
}

/// The page: the summary tables and charts, then each scene's images and tables.
pub(super) fn page(r: &Report) -> String {
    let names: Vec<String> = methods().iter().map(|m| m.name().to_string()).collect();
    let inputs: Vec<String> = std::iter::once("original".to_string())
        .chain(names.iter().cloned())
        .collect();
    html! {
        (DOCTYPE)
        html {
            head {
                meta charset="utf-8";
                title { "stereolink report" }
                style { (PreEscaped(STYLE)) }
            }
            body {
                h1 { "stereolink: the paper's experiments, rerun" }
                p {
                    (r.scenes.len()) " scenes in " (format!("{:.0}", r.seconds)) " s. Segmentation: "
                    (LEVELS) " classes (k-means k = " (LEVELS) "; " (LEVELS)
                    " levels per channel for the thresholding methods), seed " (SEED)
                    ". Matching scored against the ground truth: bad > 1 px over non-occluded \
                     pixels, dense output (invalid counts as bad). Best value per column in bold."
                }
                (segmentation_summary(r, &names))
                (matching_summary(r, &inputs))
                @for s in &r.scenes { (scene(s, &names, &inputs)) }
                script { (PreEscaped(IMAGES_LOADED)) }
            }
        }
    }
    .into_string()
}

/// Table IV and Figs. 12 and 26: each method's means over the scenes, and
/// the paper's.
fn segmentation_summary(r: &Report, names: &[String]) -> Markup {
    let seg = |m: &str, f: fn(&SegResult) -> f64| {
        mean(r.scenes.iter().filter_map(|s| s.segmentation.get(m)).map(f))
    };
    let paper_psnr = |m: &str| mean(r.scenes.iter().filter_map(|s| paper::psnr(&s.name, m)));
    // A lossy codec's mean PSNR in the method's bytes, over the scenes
    // where its smallest pair fits them (how many, when not all).
    let lossy = |m: &str, codec: &str| {
        let v: Vec<f64> = r
            .scenes
            .iter()
            .filter_map(|s| s.segmentation.get(m)?.lossy_psnr_db.get(codec).copied())
            .collect();
        let n = r.scenes.len();
        match mean(v.iter().copied()) {
            Some(db) if v.len() == n => format!("{db:.2}"),
            Some(db) => format!("{db:.2} ({} of {n})", v.len()),
            None => "–".into(),
        }
    };
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
                lossy(m, "webp"),
                lossy(m, "jpeg"),
                f(seg(m, |s| s.time_ms), 1),
            ]
        })
        .collect();
    let head = [
        "method",
        "PSNR dB",
        "PSNR on the paper's scenes",
        "paper PSNR",
        "difference",
        "reduction %",
        "paper 95 % CI",
        "coded pair B",
        "WebP PSNR dB in those bytes",
        "JPEG PSNR dB in those bytes",
        "time ms",
    ];
    let (lower, higher, none) = (Some(true), Some(false), None);
    let lower = [
        none, higher, higher, none, none, higher, none, lower, none, none, lower,
    ];
    let of = |f: &dyn Fn(&str) -> Option<f64>| names.iter().map(|m| f(m)).collect::<Vec<_>>();
    let psnr = svg::bars(
        "PSNR of the segmented left view (dB)",
        "dB",
        names,
        &[
            ("ours".into(), of(&|m| seg(m, |s| s.psnr_db))),
            ("paper".into(), of(&paper_psnr)),
        ],
    );
    let reduction = svg::bars(
        "Size reduction against the original PNG pair (%)",
        "%",
        names,
        &[
            ("ours".into(), of(&|m| seg(m, |s| s.reduction_percent))),
            (
                "paper CI low".into(),
                of(&|m| paper::reduction_ci(m).map(|c| c.0)),
            ),
            (
                "paper CI high".into(),
                of(&|m| paper::reduction_ci(m).map(|c| c.1)),
            ),
        ],
    );
    let time = svg::bars(
        "Segmentation time of both views (ms)",
        "ms",
        names,
        &[("ours".into(), of(&|m| seg(m, |s| s.time_ms)))],
    );
    html! {
        h2 { "Segmentation (Table IV, Fig. 12, Fig. 26), means over the scenes" }
        (table(&head, &rows, &lower))
        (PreEscaped(psnr))
        (PreEscaped(reduction))
        (PreEscaped(time))
    }
}

/// Tables V and VI and Fig. 27: each matcher on each input, means over the
/// scenes, and accuracy against time per scene.
fn matching_summary(r: &Report, inputs: &[String]) -> Markup {
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
            for a in ALGOS {
                row.push(f(m(i, a, |x| x.bad1_nonocc), 2));
            }
            for a in ALGOS {
                row.push(f(m(i, a, |x| Some(x.levels as f64)), 1));
            }
            for a in ALGOS {
                row.push(f(m(i, a, |x| Some(x.time_ms)), 1));
            }
            row
        })
        .collect();
    let head = [
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
    ];
    let (lower, none) = (Some(true), None);
    let lower = [
        none, lower, lower, lower, lower, none, none, none, none, lower, lower, lower, lower,
    ];
    let scatter = svg::scatter(
        "Accuracy against time, per scene and input",
        "matching time (ms)",
        "bad > 1 px (%)",
        &ALGOS
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
    html! {
        h2 { "Matching (Tables V and VI, Fig. 27), means over the scenes" }
        p {
            "Does segmenting first help matching? Compare each segmented input's bad-pixel rate \
             with the original pair's. The planes column matches the original pair with a plane \
             per segment of that input (the original: a mean shift over-segmentation)."
        }
        (planes_headline(inputs, |i| m(i, "planes", |x| x.bad1_nonocc)))
        (table(&head, &rows, &lower))
        (PreEscaped(scatter))
    }
}

/// One scene: its images, then its segmentation and matching tables.
fn scene(s: &SceneReport, names: &[String], inputs: &[String]) -> Markup {
    let fig = |what: &str, cap: &str| {
        html! {
            figure {
                img src=(img_name(&s.name, what)) alt=(cap);
                figcaption { (cap) }
            }
        }
    };
    let segmentation: Vec<Vec<String>> = names
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
    let matching: Vec<Vec<String>> = inputs
        .iter()
        .map(|i| {
            let mut row = vec![i.clone()];
            for a in ALGOS {
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
    let (lower, higher, none) = (Some(true), Some(false), None);
    html! {
        h2 id=(s.name) { (s.name) " (" (s.size.0) "x" (s.size.1) ", " (s.ndisp) " disparities)" }
        div.imgs {
            (fig("left", "left view"))
            (fig("anaglyph", "anaglyph (Dubois)"))
            @for n in names { (fig(&format!("seg-{n}"), n)) }
            br;
            @for input in ["original", "fodpso"] {
                @for a in ALGOS { (fig(&format!("disp-{input}-{a}"), &format!("{a} on {input}"))) }
            }
            @if s.matching["original"]["sgm"].bad1_nonocc.is_some() {
                (fig("error-sgm", "SGM errors (red: > 1 px)"))
            }
        }
        (table(
            &["method", "PSNR dB", "paper", "reduction %", "bytes", "classes", "ms"],
            &segmentation,
            &[none, higher, none, higher, lower, none, lower],
        ))
        (table(
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
            &matching,
            &[none, lower, none, lower, none, lower, none, lower, none],
        ))
    }
}
