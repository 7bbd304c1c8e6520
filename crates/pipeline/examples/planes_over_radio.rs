//! The plane table over the radio, measured on Middlebury scenes: the
//! sender (`send --algo planes`: segmenting with METHOD and LEVELS, planes
//! fitted over the transmitted left labels) makes each frame; the board
//! then takes its disparity once by WTA on the rebuilt pair and once from
//! the plane table. Prints the table's and the frame's sizes and bad > 1 px
//! (non-occluded, invalid counts as bad) of both board maps.
//!
//! ```sh
//! cargo build --release --example planes_over_radio
//! target/release/examples/planes_over_radio fodpso 3 $STEREOLINK_DATA/{tsukuba,venus,teddy,cones}
//! ```
//!
//! With `rebuild N` first, only the board's rebuild from the planes runs,
//! N times on the first scene's frame (one thread), for callgrind: the
//! difference of N = 11 and N = 1 over 10 is one rebuild's cost.
//!
//! ```sh
//! RAYON_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file=/tmp/pl11 \
//!   target/release/examples/planes_over_radio rebuild 11 fodpso 3 $STEREOLINK_DATA/cones
//! ```

use std::time::Duration;

use stereolink_codec::planetable::TableCoding;
use stereolink_codec::{container, Limits, Message};
use stereolink_image::{metrics, Scene};
use stereolink_pipeline::receiver::{BoardReceiver, DisparitySource, Event};
use stereolink_pipeline::sender::{prepare, SenderConfig};
use stereolink_segment::carry::default_margin;
use stereolink_stereo::depth::LevelSpec;
use stereolink_stereo::{Algorithm, MatchSpec};

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let rebuilds = match args.first().map(String::as_str) {
        Some("rebuild") => {
            let n = args[1].parse()?;
            args.drain(..2);
            Some(n)
        }
        _ => None,
    };
    anyhow::ensure!(
        args.len() >= 3,
        "usage: [rebuild N] METHOD LEVELS SCENE_DIR..."
    );
    let method: stereolink_segment::Method = args[0].parse()?;
    let levels: usize = args[1].parse()?;
    println!("scene     frame B  table B  segments  planes  board WTA %  board planes %");
    for dir in &args[2..] {
        let scene = Scene::load(dir)?;
        let max_disp = scene.calib.ndisp.saturating_sub(1);
        let cfg = SenderConfig {
            carry_margin: Some(default_margin(&method)),
            method: method.clone(),
            levels,
            seed: 1,
            matcher: MatchSpec::new(Algorithm::Planes, 0, max_disp)?,
            roi: None,
            levels_spec: LevelSpec::default(),
            plane_table: TableCoding::default(),
            coding: stereolink_pipeline::coding::CodingSpec::default(),
        };
        let p = prepare(&scene.left, &scene.right, &scene.calib, &cfg, (1, 0))?;
        let board = |source| {
            let mut b = BoardReceiver::new(max_disp, 9, Duration::from_secs(10));
            b.source = source;
            b
        };
        let mut planes = board(DisparitySource::Planes);
        if let Some(n) = rebuilds {
            for _ in 0..n {
                expect_frame(planes.handle(&p.frame_bytes))?;
            }
            println!("{n} frames rebuilt from planes");
            return Ok(());
        }
        let mut wta = board(DisparitySource::Wta);
        expect_frame(wta.handle(&p.frame_bytes))?;
        expect_frame(planes.handle(&p.frame_bytes))?;
        // The table's size: the frame's bytes less the same frame without it.
        let (_, msg) = container::decode(&p.frame_bytes, &Limits::default())?;
        let Message::StereoFrame(mut frame) = msg else {
            anyhow::bail!("not a frame")
        };
        let table = frame.planes.take().expect("a plane table");
        let without = container::encode(&Message::StereoFrame(frame), 1, 0).len();
        let gt = scene.gt_left.as_ref().expect("ground truth");
        let bad = |d| {
            metrics::bad_pixel_rate(d, gt, scene.masks.nonocc.as_ref(), 1.0).unwrap_or(f64::NAN)
        };
        println!(
            "{:<9} {:>7}  {:>7}  {:>8}  {:>6}  {:>11.2}  {:>14.2}",
            scene.name,
            p.frame_bytes.len(),
            p.frame_bytes.len() - without,
            table.of_segment.len(),
            table.planes.len(),
            bad(&wta.disparity()),
            bad(&planes.disparity()),
        );
        anyhow::ensure!(planes.disparity() == p.disparity, "the board's map differs");
    }
    Ok(())
}

fn expect_frame(event: Event) -> anyhow::Result<()> {
    match event {
        Event::Frame { .. } => Ok(()),
        other => anyhow::bail!("unexpected {other:?}"),
    }
}
