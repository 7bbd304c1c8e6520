//! `stereolink demo`: the whole system on the built-in synthetic scene (or a
//! real one) over a simulated XBee link with 10 % frame loss.

use std::path::PathBuf;

use anyhow::Context;
use stereolink_codec::planetable::TableCoding;
use stereolink_image::synth::{synthesize, SynthSpec};
use stereolink_image::Scene;
use stereolink_link::secure::{keyfile, public_key, Keys};
use stereolink_link::sim::SimConfig;
use stereolink_pipeline::demo::{run as run_demo, DemoConfig};
use stereolink_pipeline::sender::SenderConfig;
use stereolink_pipeline::sensor::Sensor;
use stereolink_stereo::depth::LevelSpec;

use super::calib::metres_per_unit;
use super::matching::MatcherArgs;
use super::segment::SegmentArgs;

/// Arguments of `stereolink demo`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder for the results (sent/, received/, screen.png, report.json, ...).
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    /// Run on this scene folder instead of the built-in synthetic scene.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// The scene's views are raw: rectify them with this stereo calibration
    /// YAML first and take depth from its P1/P2 (the scene's ground truth,
    /// of the raw views, is then not used).
    #[arg(long, value_name = "FILE", requires = "scene")]
    pub calib: Option<PathBuf>,
    /// Unit of the calibration's T, the chessboard square's: m, cm or mm.
    #[arg(long, default_value = "m", value_parser = ["m", "cm", "mm"], requires = "calib")]
    pub calib_units: String,
    /// Frame loss of the simulated radio link.
    #[arg(long, default_value_t = 0.1)]
    pub loss: f64,
    /// Seed of the synthetic scene and of the simulated link.
    #[arg(long, default_value_t = 1)]
    pub sim_seed: u64,
    /// Run the simulated radio this many times faster than real time.
    #[arg(long, default_value_t = 10.0)]
    pub speedup: f64,
    /// Serve the receiver's screen on a local web viewer and wait for Ctrl-C.
    #[arg(long)]
    pub web: bool,
    /// Address of the web viewer.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub web_addr: String,
    /// Run the link unsealed (by default both ends get freshly generated
    /// keys and every message is sealed, as `send`/`receive` with keys).
    #[arg(long)]
    pub insecure: bool,
    #[command(flatten)]
    /// The segmentation method and its parameters.
    pub segment: SegmentArgs,
    #[command(flatten)]
    /// The matcher and its parameters.
    pub matcher: MatcherArgs,
}

/// A raw scene rectified by `sensor`, with its depth calibration; the
/// ground truth and masks, of the raw views, are dropped.
fn rectified_scene(scene: Scene, sensor: &Sensor) -> anyhow::Result<Scene> {
    let (left, right) =
        sensor.rectify(scene.left, scene.right, &format!("scene {}", scene.name))?;
    Ok(Scene {
        name: scene.name,
        left,
        right,
        gt_left: None,
        gt_right: None,
        masks: Default::default(),
        calib: sensor.depth,
    })
}

/// A key pair for each end, drawn for this run and paired with each other.
fn generated_keys() -> anyhow::Result<(Keys, Keys)> {
    let (a, b) = (keyfile::random_key()?, keyfile::random_key()?);
    Ok((Keys::new(a, public_key(&b)), Keys::new(b, public_key(&a))))
}

/// Runs the demo and prints its summary.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let mut scene = match &args.scene {
        Some(dir) => Scene::load(dir).context("cannot load the scene")?,
        None => synthesize(&SynthSpec {
            seed: args.sim_seed,
            ..SynthSpec::default()
        })?,
    };
    if let Some(path) = &args.calib {
        let sensor =
            Sensor::from_file(path, metres_per_unit(&args.calib_units), scene.calib.ndisp)?;
        anyhow::ensure!(
            sensor.stereo.is_some(),
            "{}: not a stereo calibration YAML; a scene's own calib.txt is read without --calib",
            path.display()
        );
        if let Some(w) = sensor.range_warning() {
            eprintln!("warning: {w}");
        }
        scene = rectified_scene(scene, &sensor)?;
    }
    let max_disp = scene.calib.ndisp.saturating_sub(1).max(1);
    let sink: Option<Box<dyn stereolink_display::Sink>> = if args.web {
        let v = stereolink_display::web::WebViewer::start(&args.web_addr)
            .with_context(|| format!("cannot serve on {}", args.web_addr))?;
        eprintln!("web viewer: {}", v.url());
        Some(Box::new(v))
    } else {
        None
    };
    let cfg = DemoConfig {
        out: args.out.clone(),
        sender: SenderConfig {
            method: args.segment.method()?,
            levels: args.segment.levels,
            seed: args.segment.seed,
            carry_margin: args.segment.carry_margin()?,
            matcher: args.matcher.depth_spec(0, max_disp)?,
            roi: None,
            levels_spec: LevelSpec::default(),
            plane_table: TableCoding::default(),
            coding: stereolink_pipeline::coding::CodingSpec::default(),
        },
        scene,
        link: SimConfig {
            loss: args.loss,
            seed: args.sim_seed,
            ..SimConfig::default()
        },
        speedup: args.speedup,
        sink,
        keys: (!args.insecure).then(generated_keys).transpose()?,
    };
    let bar = super::progress(4, "demo");
    let step = |what: &str| {
        bar.inc(1);
        bar.set_message(what.to_string());
    };
    let r = run_demo(cfg, &step)?;
    bar.finish_and_clear();
    out.emit(&r, || {
        let opt = |v: Option<f64>, unit: &str| v.map_or("unknown".into(), |v| format!("{v:.3} {unit}"));
        format!(
            "stereolink demo on {} ({}x{}), results in {}\n\
             segmented ({}): PSNR {:.2} / {:.2} dB\n\
             sent {} B (frame) + {} B (depth report) vs {} B of original PNGs: {:.1}x smaller ({:.1} % reduction)\n\
             simulated XBee link, {:.0} % frame loss: {:.2} s of radio time, {:.1} kb/s goodput, {} retransmissions of {} segments\n\
             {}\n\
             received views equal the sent ones: {}\n\
             target distance {} (ground truth {}); axis commanded {}, ended at {} (error {})\n",
            r.scene,
            r.size.0,
            r.size.1,
            args.out.display(),
            r.segmentation,
            r.psnr_db.0,
            r.psnr_db.1,
            r.frame_bytes,
            r.report_bytes,
            r.original_png_bytes,
            r.compression_ratio,
            r.reduction_percent,
            r.link_loss * 100.0,
            r.link_seconds,
            r.goodput_bps / 1e3,
            r.retransmissions,
            r.segments,
            if r.sealed {
                format!("link sealed (Noise KK) with keys generated for this run; {} messages rejected", r.rejected)
            } else {
                "link NOT sealed (--insecure): anyone in radio range could move the axis".into()
            },
            if r.received_equals_sent { "yes, bit for bit" } else { "NO" },
            opt(Some(r.distance_m), "m"),
            opt(r.true_distance_m, "m"),
            opt(r.axis_commanded_mm, "mm"),
            opt(r.axis_final_mm, "mm"),
            opt(r.axis_error_mm, "mm"),
        )
    })?;
    anyhow::ensure!(
        r.received_equals_sent,
        "the received views differ from the sent ones"
    );
    if args.web {
        eprintln!("serving the screen; press Ctrl-C to stop");
        loop {
            std::thread::park();
        }
    }
    Ok(())
}
