//! `stereolink segment` and `stereolink bench segment`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;
use stereolink_image::{io, metrics::psnr_rgb, RgbImage, Scene};
use stereolink_pipeline::sender::segment_pair;
use stereolink_segment::carry::default_margin;
use stereolink_segment::meanshift::{ColourSpace, Kernel, MeanShiftSpec};
use stereolink_segment::{segment, Method, Segmentation};

/// Segmentation options shared by the commands that segment.
#[derive(Debug, Clone, clap::Args)]
pub struct SegmentArgs {
    /// Method: kmeans, meanshift, pso, dpso, fodpso or otsu (exact multilevel Otsu).
    #[arg(long, visible_alias = "segment", default_value = "fodpso")]
    pub method: String,
    /// Classes: k for k-means, levels per channel for the thresholding methods.
    #[arg(long, default_value_t = 3)]
    pub levels: usize,
    /// Seed of the stochastic methods (same seed, same result).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Iterations: of the swarm (pso, dpso, fodpso), or the most per pixel
    /// (meanshift).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Fractional order α (fodpso).
    #[arg(long)]
    pub alpha: Option<f64>,
    /// Mean shift spatial bandwidth h_s.
    #[arg(long)]
    pub spatial: Option<usize>,
    /// Mean shift range bandwidth h_r.
    #[arg(long)]
    pub range: Option<f32>,
    /// Mean shift: a pixel stops when its shift is below this.
    #[arg(long)]
    pub threshold: Option<f32>,
    /// Mean shift range domain: luv or rgb.
    #[arg(long, value_parser = ["luv", "rgb"])]
    pub colour_space: Option<String>,
    /// Mean shift range kernel: uniform or gaussian.
    #[arg(long, value_parser = ["uniform", "gaussian"])]
    pub kernel: Option<String>,
    /// Mean shift: regions smaller than this many pixels join a neighbour.
    #[arg(long)]
    pub min_region: Option<usize>,
    /// Mean shift coarse-to-fine levels, as OpenCV's pyrMeanShiftFiltering
    /// maxLevel (0: filter every pixel, exact; 1 or more: filter a half-size
    /// copy first, then only the pixels near its boundaries).
    #[arg(long)]
    pub pyramid: Option<usize>,
    /// Mean shift with the paper's preset (h_s 40, h_r 3, threshold 3).
    #[arg(long)]
    pub paper_preset: bool,
    /// Pairs: the right view is made stereo-consistent, its labels carried
    /// over from the left view's (along the label coder's stereo shifts)
    /// wherever the right pixel's colour is consistent with the carried
    /// class within this margin: levels per channel for the thresholding
    /// methods (the class's interval widened), RGB distance beyond the
    /// distance to its own class's colour for the others. Default 6 levels
    /// for the thresholding methods, 20 for the others.
    #[arg(long)]
    pub carry_margin: Option<f32>,
    /// Pairs: segment the right view independently of the left (no labels
    /// carried over).
    #[arg(long, conflicts_with = "carry_margin")]
    pub independent_right: bool,
}

impl SegmentArgs {
    /// The method with the overrides applied.
    pub fn method(&self) -> anyhow::Result<Method> {
        let mut m: Method = self.method.parse()?;
        match &mut m {
            Method::Pso(s) | Method::Dpso(s) | Method::Fodpso(s) => {
                s.iterations = self.iterations.unwrap_or(s.iterations);
                if self.alpha.is_some() {
                    s.alpha = self.alpha;
                }
            }
            Method::MeanShift(s) => {
                if self.paper_preset {
                    *s = MeanShiftSpec::paper();
                }
                s.spatial = self.spatial.unwrap_or(s.spatial);
                s.range = self.range.unwrap_or(s.range);
                s.threshold = self.threshold.unwrap_or(s.threshold);
                s.max_iterations = self.iterations.unwrap_or(s.max_iterations);
                s.min_region = self.min_region.unwrap_or(s.min_region);
                s.pyramid = self.pyramid.unwrap_or(s.pyramid);
                match self.colour_space.as_deref() {
                    Some("rgb") => s.colour_space = ColourSpace::Rgb,
                    Some(_) => s.colour_space = ColourSpace::Luv,
                    None => {}
                }
                match self.kernel.as_deref() {
                    Some("gaussian") => s.kernel = Kernel::Gaussian,
                    Some(_) => s.kernel = Kernel::Uniform,
                    None => {}
                }
            }
            Method::KMeans | Method::Otsu => {}
        }
        Ok(m)
    }

    /// Segments one image.
    pub fn run(&self, image: &RgbImage) -> anyhow::Result<Segmentation> {
        Ok(segment(image, &self.method()?, self.levels, self.seed)?)
    }

    /// The carry margin of a pair's right view (`None`: independent).
    pub fn carry_margin(&self) -> anyhow::Result<Option<f32>> {
        if self.independent_right {
            return Ok(None);
        }
        let margin = self.carry_margin.unwrap_or(default_margin(&self.method()?));
        if !(margin >= 0.0 && margin.is_finite()) {
            anyhow::bail!("--carry-margin {margin} must be a finite number ≥ 0");
        }
        Ok(Some(margin))
    }

    /// Segments a pair, the right view stereo-consistent unless `--independent-right`.
    pub fn run_pair(
        &self,
        left: &RgbImage,
        right: &RgbImage,
    ) -> anyhow::Result<(Segmentation, Segmentation)> {
        segment_pair(
            (left, right),
            &self.method()?,
            (self.levels, self.seed),
            self.carry_margin()?,
        )
    }
}

/// Arguments of `stereolink segment`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input image (PNG, PPM, PGM).
    pub input: PathBuf,
    /// Output segmented image (PNG).
    #[arg(short, long)]
    pub output: PathBuf,
    /// A second view (the right image of a pair), segmented the same way.
    #[arg(long, requires = "right_output")]
    pub right: Option<PathBuf>,
    /// Where to write the segmented second view.
    #[arg(long)]
    pub right_output: Option<PathBuf>,
    #[command(flatten)]
    /// The segmentation method and its parameters.
    pub segment: SegmentArgs,
}

/// What one segmented view reports.
#[derive(Serialize)]
pub struct Report {
    input: PathBuf,
    output: PathBuf,
    method: String,
    classes: usize,
    psnr_db: f64,
    /// Segmentation time; of both views when a pair is segmented.
    time_ms: f64,
    iterations: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    thresholds: Option<[Vec<u8>; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    fitness: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    optimum: Option<[f64; 3]>,
}

/// The report of `seg`, a segmentation of `img` (read from `input`) that
/// took `time_ms`, after writing it to `output`.
fn report(
    (input, output): (&PathBuf, &PathBuf),
    args: &SegmentArgs,
    (img, seg): (&RgbImage, &Segmentation),
    time_ms: f64,
) -> anyhow::Result<Report> {
    let rgb = seg.to_rgb();
    io::write_rgb(output, &rgb)?;
    let ch = seg.channels.as_ref();
    Ok(Report {
        input: input.clone(),
        output: output.clone(),
        method: args.method()?.name().into(),
        classes: seg.image.palette().len(),
        psnr_db: psnr_rgb(img, &rgb)?.overall,
        time_ms,
        iterations: seg.iterations,
        thresholds: ch.map(|c| c.thresholds.clone()),
        fitness: ch.map(|c| c.fitness),
        optimum: ch.map(|c| c.optimum),
    })
}

/// Segments one image or both views of a pair.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let left = io::read_rgb(&args.input)?;
    let cannot = || format!("cannot segment {}", args.input.display());
    let t = Instant::now();
    let reports = match (&args.right, &args.right_output) {
        (Some(r), Some(ro)) => {
            // A pair is segmented as one (the right view may depend on the
            // left): each view reports the pair's time.
            let right = io::read_rgb(r)?;
            let (sl, sr) = args.segment.run_pair(&left, &right).with_context(cannot)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            vec![
                report((&args.input, &args.output), &args.segment, (&left, &sl), ms)?,
                report((r, ro), &args.segment, (&right, &sr), ms)?,
            ]
        }
        _ => {
            if args.segment.carry_margin.is_some() || args.segment.independent_right {
                anyhow::bail!(
                    "--carry-margin and --independent-right apply to a pair: \
                     give --right and --right-output too"
                );
            }
            let seg = args.segment.run(&left).with_context(cannot)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            vec![report(
                (&args.input, &args.output),
                &args.segment,
                (&left, &seg),
                ms,
            )?]
        }
    };
    let human = || {
        reports
            .iter()
            .map(|r| {
                format!(
                    "{} → {}: {} classes by {}, PSNR {:.2} dB, {:.1} ms\n",
                    r.input.display(),
                    r.output.display(),
                    r.classes,
                    r.method,
                    r.psnr_db,
                    r.time_ms
                )
            })
            .collect::<String>()
    };
    if reports.len() == 1 {
        out.emit(&reports[0], human)
    } else {
        out.emit(&reports, human)
    }
}

/// Arguments of `stereolink bench segment`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Scene folder; its left view is segmented.
    #[arg(long)]
    pub scene: PathBuf,
    /// Timed runs after one warm-up run.
    #[arg(long, default_value_t = 5)]
    pub iters: usize,
    #[command(flatten)]
    /// The segmentation method and its parameters.
    pub segment: SegmentArgs,
}

#[derive(Serialize)]
struct Bench {
    method: String,
    scene: String,
    levels: usize,
    iters: usize,
    median_ms: f64,
    psnr_db: f64,
    fitness: Option<[f64; 3]>,
    optimum: Option<[f64; 3]>,
    fitness_fraction: Option<f64>,
    /// k-means objective J (sum of squared RGB distances to the centres).
    objective: Option<f64>,
}

/// Times the method alone on an image in memory.
pub fn run_bench(args: BenchArgs, out: &super::Output) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene)?;
    let seg = args.segment.run(&scene.left)?;
    let mut times = Vec::new();
    for _ in 0..args.iters.max(1) {
        let t = Instant::now();
        std::hint::black_box(args.segment.run(&scene.left)?);
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let ch = seg.channels.as_ref();
    let b = Bench {
        method: args.segment.method()?.name().into(),
        scene: scene.name.clone(),
        levels: args.segment.levels,
        iters: times.len(),
        median_ms: times[times.len() / 2],
        psnr_db: psnr_rgb(&scene.left, &seg.to_rgb())?.overall,
        fitness: ch.map(|c| c.fitness),
        optimum: ch.map(|c| c.optimum),
        fitness_fraction: ch
            .map(|c| c.fitness.iter().sum::<f64>() / c.optimum.iter().sum::<f64>().max(1e-12)),
        objective: match args.segment.method()? {
            Method::KMeans => Some(
                stereolink_segment::kmeans::cluster(
                    &scene.left,
                    args.segment.levels,
                    args.segment.seed,
                )?
                .objective,
            ),
            _ => None,
        },
    };
    out.emit(&b, || {
        format!(
            "{} on {} ({} levels): median {:.2} ms over {} runs, PSNR {:.2} dB{}\n",
            b.method,
            b.scene,
            b.levels,
            b.median_ms,
            b.iters,
            b.psnr_db,
            b.fitness_fraction.map_or(String::new(), |f| format!(
                ", fitness {:.3} % of the optimum",
                f * 100.0
            ))
        )
    })
}
