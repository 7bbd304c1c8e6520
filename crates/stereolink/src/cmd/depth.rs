//! `stereolink depth`: depth map, point cloud, region distances and depth
//! levels from a disparity map.

use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;
use stereolink_image::{io, pfm, RgbImage};
use stereolink_stereo::depth::{
    depth_levels, depth_map, region_distance, write_ply, LevelSpec, Roi,
};

use super::calib::CalibArgs;

/// Arguments of `stereolink depth`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Disparity map (PFM, `inf` = invalid).
    pub disparity: PathBuf,
    #[command(flatten)]
    /// The rig's calibration: focal length, baseline and doffs, or a stereo calibration file.
    pub calib: CalibArgs,
    /// Write the depth map (metres, PFM).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Write a PLY point cloud (x, y, z, r, g, b) coloured by this image, or gray.
    #[arg(long)]
    pub ply: Option<PathBuf>,
    /// Image that colours the point cloud (the left view).
    #[arg(long)]
    pub colour: Option<PathBuf>,
    /// Regions x,y,w,h whose distance to print (repeat for several; two give their separation).
    #[arg(long)]
    pub roi: Vec<Roi>,
    /// Depth levels: smallest share of valid pixels a level must hold.
    #[arg(long, default_value_t = LevelSpec::default().min_share)]
    pub level_min_share: f64,
    /// Depth levels: smallest distance between two levels, px of disparity.
    #[arg(long, default_value_t = LevelSpec::default().min_separation)]
    pub level_min_separation: f32,
    /// Depth levels: Gaussian smoothing of the histogram, bins.
    #[arg(long, default_value_t = LevelSpec::default().sigma)]
    pub level_sigma: f32,
}

#[derive(Serialize)]
struct Report {
    levels: Vec<stereolink_stereo::depth::Level>,
    regions: Vec<(Roi, Option<f64>)>,
    separation_m: Option<f64>,
    points: Option<usize>,
}

/// Computes and writes what was asked.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let disp = pfm::read(&args.disparity)?;
    let calib = args.calib.calibration(0)?;
    if let Some(o) = &args.output {
        pfm::write(o, &depth_map(&disp, &calib)?)?;
    }
    let points = match &args.ply {
        Some(p) => {
            let colours = match &args.colour {
                Some(c) => io::read_rgb(c)?,
                None => RgbImage::new(disp.width(), disp.height(), [200, 200, 200]),
            };
            anyhow::ensure!(
                colours.dims() == disp.dims(),
                "the colour image is {:?}, the disparity {:?}",
                colours.dims(),
                disp.dims()
            );
            let mut f = std::io::BufWriter::new(
                std::fs::File::create(p)
                    .with_context(|| format!("cannot create {}", p.display()))?,
            );
            Some(write_ply(&mut f, &disp, &colours, &calib)?)
        }
        None => None,
    };
    let regions: Vec<(Roi, Option<f64>)> = args
        .roi
        .iter()
        .map(|&r| Ok((r, region_distance(&disp, r, &calib)?)))
        .collect::<anyhow::Result<_>>()?;
    let separation = match regions.as_slice() {
        [(_, Some(a)), (_, Some(b))] => Some((a - b).abs()),
        _ => None,
    };
    let spec = LevelSpec {
        min_share: args.level_min_share,
        min_separation: args.level_min_separation,
        sigma: args.level_sigma,
        ..LevelSpec::default()
    };
    let levels = depth_levels(&disp, &spec).levels;
    let r = Report {
        levels,
        regions,
        separation_m: separation,
        points,
    };
    out.emit(&r, || {
        let mut s = format!("{} depth levels:", r.levels.len());
        for l in &r.levels {
            s += &format!(" {:.1} px ({:.0} %)", l.disparity, l.share * 100.0);
        }
        s += "\n";
        for (roi, d) in &r.regions {
            s += &format!(
                "region {},{},{},{}: {}\n",
                roi.x,
                roi.y,
                roi.w,
                roi.h,
                d.map_or("no valid disparity".into(), |d| format!("{d:.4} m"))
            );
        }
        if let Some(sep) = r.separation_m {
            s += &format!("separation: {:.2} cm\n", sep * 100.0);
        }
        if let Some(n) = r.points {
            s += &format!("point cloud: {n} points\n");
        }
        s
    })
}
