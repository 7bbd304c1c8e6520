//! Writes the seeds of the fuzz targets (`fuzz/seeds/TARGET/`): real
//! messages of each kind the targets parse, small enough to mutate fast, so
//! that a short run in CI starts deep inside the parsers instead of at
//! their first check. The seeds are kept in the repository; run this again
//! when a format changes.
//!
//! ```sh
//! cargo run --release -p stereolink-pipeline --example fuzz_seeds -- fuzz/seeds
//! ```

use std::path::{Path, PathBuf};

use stereolink_calib::files::opencv::from_opencv_yaml;
use stereolink_calib::files::ros::{to_camera_info_yaml, Side};
use stereolink_codec::control::{Command, Reply};
use stereolink_codec::lossy::{LossyCodec, ViewCoding};
use stereolink_codec::planetable::TableCoding;
use stereolink_codec::temporal::SkipSpec;
use stereolink_image::synth::{synthesize, SynthSpec};
use stereolink_image::RgbImage;
use stereolink_pipeline::coding::CodingSpec;
use stereolink_pipeline::sender::{prepare, SenderConfig};
use stereolink_pipeline::stream::StreamEncoder;
use stereolink_segment::Method;
use stereolink_stereo::depth::LevelSpec;
use stereolink_stereo::{Algorithm, MatchSpec};

fn main() -> anyhow::Result<()> {
    let out: PathBuf = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "fuzz/seeds".into())
        .into();
    let scene = synthesize(&SynthSpec {
        width: 64,
        height: 48,
        max_disp: 12,
        seed: 3,
    })?;
    let (left, right, calib) = (&scene.left, &scene.right, &scene.calib);
    let config = |algorithm, coding| -> anyhow::Result<SenderConfig> {
        Ok(SenderConfig {
            carry_margin: None,
            method: Method::KMeans,
            levels: 3,
            seed: 1,
            matcher: MatchSpec::new(algorithm, 0, 11)?,
            roi: None,
            levels_spec: LevelSpec::default(),
            plane_table: TableCoding::default(),
            coding: CodingSpec {
                coding,
                quality: 30,
                budget: None,
                stereo_prediction: true,
            },
        })
    };
    let webp = ViewCoding::Lossy(LossyCodec::Webp);
    let jpeg = ViewCoding::Lossy(LossyCodec::Jpeg);

    let segmented = prepare(
        left,
        right,
        calib,
        &config(Algorithm::Wta, ViewCoding::Segmented)?,
        (1, 0),
    )?;
    let planes = prepare(
        left,
        right,
        calib,
        &config(Algorithm::Planes, ViewCoding::Segmented)?,
        (2, 0),
    )?;
    let lossy: Vec<_> = [webp, jpeg]
        .into_iter()
        .map(|c| Ok(prepare(left, right, calib, &config(Algorithm::Wta, c)?, (3, 0))?.frame_bytes))
        .collect::<anyhow::Result<_>>()?;
    let control: Vec<Vec<u8>> = vec![
        Command::AxisStop.encode(1),
        Command::SetLevels(4).encode(2),
        Command::SetMethod("fodpso".into()).encode(3),
        Reply {
            id: 4,
            result: Err("no axis".into()),
        }
        .encode(),
    ];

    let frames = [
        &segmented.frame_bytes,
        &planes.frame_bytes,
        &lossy[0],
        &lossy[1],
    ];
    for target in ["decode", "frame_decoder"] {
        write(&out, target, frames.iter().map(|f| f.as_slice()))?;
        write(&out, target, [segmented.report_bytes.as_slice()])?;
    }
    write(&out, "plane_table", [planes.frame_bytes.as_slice()])?;
    write(&out, "control", control.iter().map(Vec::as_slice))?;
    for coding in [webp, ViewCoding::Segmented] {
        write(
            &out,
            "stream",
            [stream(left, right, &scene.calib, &config(Algorithm::Wta, coding)?)?.as_slice()],
        )?;
    }

    let golden = include_str!("../../link/tests/golden/xbee_vectors.txt");
    let xbee: Vec<Vec<u8>> = golden
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_whitespace().nth(2))
        .map(hex)
        .collect();
    write(&out, "xbee_parser", xbee.iter().map(Vec::as_slice))?;

    let opencv = include_str!("../../calib/tests/data/opencv_stereo.yml");
    let rig = from_opencv_yaml(opencv, Path::new("opencv_stereo.yml"))?;
    let yaml = [
        opencv.to_string(),
        to_camera_info_yaml(&rig, Side::Right, "right"),
    ];
    write(&out, "calib_yaml", yaml.iter().map(String::as_bytes))?;
    Ok(())
}

/// A key frame and three frames predicted from the one before (the second
/// of a moved scene, the third of the scene panned: predicted by motion),
/// each after its length as the `stream` target reads them.
fn stream(
    left: &RgbImage,
    right: &RgbImage,
    calib: &stereolink_image::Calibration,
    cfg: &SenderConfig,
) -> anyhow::Result<Vec<u8>> {
    let mut encoder = StreamEncoder::new(SkipSpec::default());
    let (mut moved_l, mut moved_r) = (left.clone(), right.clone());
    for p in moved_l.as_mut_slice()[..400]
        .iter_mut()
        .chain(&mut moved_r.as_mut_slice()[..400])
    {
        *p = [255, 0, 0];
    }
    let (w, h) = left.dims();
    let panned = |v: &RgbImage| {
        RgbImage::from_fn(w, h, |x, y| v.get((x + 2).min(w - 1), (y + 1).min(h - 1)))
    };
    let (panned_l, panned_r) = (panned(&moved_l), panned(&moved_r));
    let mut out = Vec::new();
    let pairs = [
        (left, right),
        (left, right),
        (&moved_l, &moved_r),
        (&panned_l, &panned_r),
    ];
    for (id, (l, r)) in pairs.into_iter().enumerate() {
        let id = id as u32 + 1;
        let (prepared, _) =
            encoder.prepare((l, r), calib, cfg, (id, u64::from(id) * 100_000), false)?;
        encoder.acknowledge(id);
        out.extend_from_slice(&u16::try_from(prepared.frame_bytes.len())?.to_le_bytes());
        out.extend_from_slice(&prepared.frame_bytes);
    }
    Ok(out)
}

/// Writes each seed as `TARGET/NAME`, named by its content's hash.
fn write<'a>(
    out: &Path,
    target: &str,
    seeds: impl IntoIterator<Item = &'a [u8]>,
) -> anyhow::Result<()> {
    let dir = out.join(target);
    std::fs::create_dir_all(&dir)?;
    for seed in seeds {
        let name = format!("{:08x}", stereolink_link::crc::crc32(seed));
        std::fs::write(dir.join(name), seed)?;
    }
    Ok(())
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .filter_map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).ok())
        .collect()
}
