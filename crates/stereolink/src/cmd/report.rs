//! `stereolink report`: the paper's experiments rerun on a data folder, as an
//! HTML page with tables, images and plots, and `report.json`.

use std::path::PathBuf;

use serde::Serialize;

use super::eval::scene_dirs;

/// Arguments of `stereolink report`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A folder of scene folders (e.g. ../shared/data/middlebury), or one scene.
    #[arg(long)]
    pub data: PathBuf,
    /// Where to write index.html, img/ and report.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Only these scenes (comma-separated folder names).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
}

#[derive(Serialize)]
struct Done {
    out: PathBuf,
    scenes: usize,
    seconds: f64,
}

/// Runs the experiments and writes the report.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let dirs = scene_dirs(&args.data, &args.scenes)?;
    let bar = super::progress(dirs.len() as u64, "report");
    let step = |name: &str| {
        bar.set_message(name.to_string());
        bar.inc(1);
    };
    let r = stereolink_report::run(&dirs, &args.out, &step)?;
    bar.finish_and_clear();
    let d = Done {
        out: args.out.join("index.html"),
        scenes: r.scenes.len(),
        seconds: r.seconds,
    };
    out.emit(&d, || {
        format!(
            "report on {} scenes written to {} in {:.0} s\n",
            d.scenes,
            d.out.display(),
            d.seconds
        )
    })
}
