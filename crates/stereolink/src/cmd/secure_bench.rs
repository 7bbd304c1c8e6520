//! `stereolink bench open`: what the board spends to verify and decrypt one
//! sealed frame. A frame file (from `stereolink encode`) or a message of
//! `--bytes` is sealed once and opened `--runs` times; the median time is
//! printed, and `valgrind --tool=callgrind --toggle-collect='*Channel*open*'`
//! counts the instructions of the opens alone.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use stereolink_link::arq::SessionId;
use stereolink_link::secure::{public_key, Channel, Keys, Opened, SecureConfig};

/// Arguments of `stereolink bench open`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// An encoded frame to seal and open (default: --bytes of test data).
    #[arg(long)]
    pub frame: Option<PathBuf>,
    /// Message size without --frame.
    #[arg(long, default_value_t = 30_000)]
    pub bytes: usize,
    /// Opens timed.
    #[arg(long, default_value_t = 20)]
    pub runs: usize,
}

/// Seals once, opens `runs` times (each under a fresh counter), prints the median.
pub fn run_bench(args: BenchArgs, out: &super::Output) -> anyhow::Result<()> {
    let message = match &args.frame {
        Some(p) => std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?,
        None => (0..args.bytes).map(|i| (i * 31) as u8).collect(),
    };
    let (a, b) = ([0x11; 32], [0x22; 32]);
    let mut tx = Channel::new(Keys::new(a, public_key(&b)), SecureConfig::default());
    let mut rx = Channel::new(Keys::new(b, public_key(&a)), SecureConfig::default());
    let (sa, sb) = (SessionId(1), SessionId(2));
    let init = tx.initiate(sa)?;
    let Opened::Reply(resp) = rx.open(sa, sb, &init, 0) else {
        anyhow::bail!("the handshake failed");
    };
    anyhow::ensure!(
        tx.open(sb, sa, &resp, 0) == Opened::Established,
        "the handshake failed"
    );
    let mut times = Vec::with_capacity(args.runs);
    for _ in 0..args.runs.max(1) {
        let sealed = tx.seal(&message)?;
        let start = Instant::now();
        let opened = rx.open(sa, sb, std::hint::black_box(&sealed), 0);
        times.push(start.elapsed().as_secs_f64() * 1e3);
        anyhow::ensure!(
            opened == Opened::Message(message.clone()),
            "a sealed frame did not open"
        );
    }
    times.sort_by(f64::total_cmp);
    let median_ms = times[times.len() / 2];
    out.emit(
        &serde_json::json!({ "bytes": message.len(), "runs": times.len(), "median_ms": median_ms }),
        || {
            format!(
                "open (verify + decrypt) of {} B: median {median_ms:.3} ms over {} runs\n",
                message.len(),
                times.len()
            )
        },
    )
}
