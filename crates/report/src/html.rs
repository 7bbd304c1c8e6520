//! The report's HTML page: the summary tables and charts against the
//! paper's figures, then each scene's images and tables. Rendering only:
//! every number comes from the [`Report`] that `report` computed.

use super::{img_name, methods, paper, svg, MatchResult, Report, SegResult, LEVELS, SEED};

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

/// The page: the summary tables and charts, then each scene's images and tables.
pub(super) fn page(r: &Report) -> String {
    let names: Vec<String> = methods().iter().map(|m| m.name().to_string()).collect();
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
                lossy(m, "webp"),
                lossy(m, "jpeg"),
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
            "WebP PSNR dB in those bytes",
            "JPEG PSNR dB in those bytes",
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
            None,
            None,
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
