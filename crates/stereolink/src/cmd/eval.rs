//! `stereolink eval`: Middlebury bad-pixel scores of the matchers on a data folder.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use stereolink_image::{metrics::bad_pixel_rate, Scene};
use stereolink_pipeline::planes::disparity;
use stereolink_stereo::{Algorithm, Matcher};

use super::matching::MatcherArgs;

/// Arguments of `stereolink eval`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A folder of scene folders (e.g. ../shared/data/middlebury) or one scene folder.
    #[arg(long)]
    pub data: PathBuf,
    /// Only these scenes (comma-separated folder names).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// Algorithms to score (comma-separated); default: the one of --algo.
    #[arg(long = "algos", value_delimiter = ',')]
    pub algos: Vec<String>,
    #[command(flatten)]
    /// The matcher and its parameters.
    pub matcher: MatcherArgs,
}

/// Bad-pixel percentages of one scene and algorithm (`None`: mask absent).
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// Scene name.
    pub scene: String,
    /// Algorithm.
    pub algorithm: Algorithm,
    /// Bad > 1 px over non-occluded pixels.
    pub bad1_nonocc: Option<f64>,
    /// Bad > 1 px over all pixels with ground truth.
    pub bad1_all: Option<f64>,
    /// Bad > 1 px near discontinuities.
    pub bad1_disc: Option<f64>,
    /// Bad > 2 px over non-occluded pixels.
    pub bad2_nonocc: Option<f64>,
    /// Bad > 2 px over all pixels with ground truth.
    pub bad2_all: Option<f64>,
    /// Bad > 2 px near discontinuities.
    pub bad2_disc: Option<f64>,
    /// Matching time.
    pub time_ms: f64,
}

/// The scene folders under `data` (or `data` itself when it is a scene).
pub fn scene_dirs(data: &Path, only: &[String]) -> anyhow::Result<Vec<PathBuf>> {
    if data.join("left.png").is_file() || data.join("im0.png").is_file() {
        return Ok(vec![data.to_path_buf()]);
    }
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(data)
        .with_context(|| format!("cannot read the data folder {}", data.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .filter(|p| {
            only.is_empty()
                || only
                    .iter()
                    .any(|s| p.file_name().is_some_and(|n| n == s.as_str()))
        })
        .collect();
    dirs.sort();
    anyhow::ensure!(
        !dirs.is_empty(),
        "{}: no scene folders found",
        data.display()
    );
    Ok(dirs)
}

/// Scores `algorithm` on a loaded scene.
pub fn score(scene: &Scene, algorithm: Algorithm, matcher: &MatcherArgs) -> anyhow::Result<Row> {
    let mut m = matcher.clone();
    m.algo = algorithm;
    let spec = m.spec(0, scene.calib.ndisp.saturating_sub(1))?;
    let segments = m.segments()?;
    let start = Instant::now();
    let pair = (&scene.left, &scene.right);
    let d = disparity(&mut Matcher::new(), pair, &spec, &segments)?;
    let time_ms = start.elapsed().as_secs_f64() * 1e3;
    let gt = scene
        .gt_left
        .as_ref()
        .with_context(|| format!("{}: no ground truth", scene.name))?;
    let s = |mask: Option<&stereolink_image::Mask>, t: f32, required: bool| {
        if required && mask.is_none() {
            None
        } else {
            bad_pixel_rate(&d, gt, mask, t)
        }
    };
    let masks = &scene.masks;
    Ok(Row {
        scene: scene.name.clone(),
        algorithm,
        bad1_nonocc: s(masks.nonocc.as_ref(), 1.0, true),
        bad1_all: s(masks.all.as_ref(), 1.0, false),
        bad1_disc: s(masks.disc.as_ref(), 1.0, true),
        bad2_nonocc: s(masks.nonocc.as_ref(), 2.0, true),
        bad2_all: s(masks.all.as_ref(), 2.0, false),
        bad2_disc: s(masks.disc.as_ref(), 2.0, true),
        time_ms,
    })
}

#[derive(Serialize)]
struct Table {
    rows: Vec<Row>,
    averages: Vec<Row>,
}

fn average(rows: &[Row], algorithm: Algorithm) -> Row {
    let pick = |f: fn(&Row) -> Option<f64>| {
        let v: Vec<f64> = rows
            .iter()
            .filter(|r| r.algorithm == algorithm)
            .filter_map(f)
            .collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    Row {
        scene: "average".into(),
        algorithm,
        bad1_nonocc: pick(|r| r.bad1_nonocc),
        bad1_all: pick(|r| r.bad1_all),
        bad1_disc: pick(|r| r.bad1_disc),
        bad2_nonocc: pick(|r| r.bad2_nonocc),
        bad2_all: pick(|r| r.bad2_all),
        bad2_disc: pick(|r| r.bad2_disc),
        time_ms: pick(|r| Some(r.time_ms)).unwrap_or(0.0),
    }
}

/// Scores the matchers on every scene and prints the table.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let algos: Vec<Algorithm> = if args.algos.is_empty() {
        vec![args.matcher.algo]
    } else {
        args.algos
            .iter()
            .map(|a| a.parse())
            .collect::<Result<_, _>>()?
    };
    let dirs = scene_dirs(&args.data, &args.scenes)?;
    let progress = super::progress(dirs.len() as u64, "scoring");
    let mut rows = Vec::new();
    for dir in &dirs {
        let scene = Scene::load(dir)?;
        progress.set_message(scene.name.clone());
        for &a in &algos {
            rows.push(score(&scene, a, &args.matcher)?);
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    let averages: Vec<Row> = algos.iter().map(|&a| average(&rows, a)).collect();
    let table = Table { rows, averages };
    out.emit(&table, || {
        let f = |v: Option<f64>| v.map_or("    -".to_string(), |v| format!("{v:5.2}"));
        let mut s = String::from(
            "scene        algo  bad1 nonocc   all  disc | bad2 nonocc   all  disc |   time ms\n",
        );
        for r in table.rows.iter().chain(&table.averages) {
            s += &format!(
                "{:<12} {:<6}     {}  {}  {} |       {}  {}  {} | {:9.1}\n",
                r.scene,
                r.algorithm.name(),
                f(r.bad1_nonocc),
                f(r.bad1_all),
                f(r.bad1_disc),
                f(r.bad2_nonocc),
                f(r.bad2_all),
                f(r.bad2_disc),
                r.time_ms
            );
        }
        s
    })
}
