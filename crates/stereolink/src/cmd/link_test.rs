//! `stereolink link-test`: send test messages over a link and report goodput,
//! loss and retransmissions. On a `sim:` link it runs the ARQ over the
//! simulated 802.15.4 channel in simulated time (and `--sweep` prints the loss
//! sweep); over several `sim:` links, a bond of simulated radio pairs, both
//! ends run in this process in real time; on real links one process runs
//! `--role send` and the other `--role receive`.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use stereolink_link::arq::{Config, DATA_OVERHEAD};
use stereolink_link::bond::Bond;
use stereolink_link::endpoint::Endpoint;
use stereolink_link::secure::sim::sealed_transfer;
use stereolink_link::sim::{self, SimConfig};
use stereolink_link::spec::{self, LinkSpec};
use stereolink_link::transport::Notice;

/// Which side this process plays on a real link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Role {
    /// Send the test messages.
    Send,
    /// Receive and verify them.
    Receive,
}

/// Arguments of `stereolink link-test`.
#[derive(Clone, Debug, clap::Args)]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, sim:?loss=0.1&seed=3, fallback:A,B;
    /// several make a bond.
    ///
    /// Several sim: links are that many simulated radio pairs (pair i with
    /// the spec's seed + i) bonded at both ends in this process, run in real
    /// time and timed in radio time. Several real links bond as in `send
    /// --help`; both ends give the same number of --link.
    #[arg(long, default_value = "sim:?loss=0.1&seed=1")]
    pub link: Vec<String>,
    /// Messages to send.
    #[arg(long, default_value_t = 5)]
    pub count: usize,
    /// Bytes per message.
    #[arg(long, default_value_t = 30_000)]
    pub size: usize,
    /// Seed of the message contents (both sides must agree).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// On a sim link: print the loss sweep (0, 1, 5, 10, 20, 30 %) instead.
    #[arg(long)]
    pub sweep: bool,
    /// With --sweep: also seal the message with the secure layer (Noise KK,
    /// after a simulated handshake) and print the goodput with and without
    /// keys, averaged over --count seeds, and the handshake's time.
    #[arg(long, requires = "sweep")]
    pub keys: bool,
    /// On a real link: this process sends or receives.
    #[arg(long, value_enum)]
    pub role: Option<Role>,
    /// Receiver: give up after this many seconds without a message.
    #[arg(long, default_value_t = 60)]
    pub timeout_s: u64,
}

/// The deterministic test message `i`.
pub fn test_message(seed: u64, i: usize, size: usize) -> Vec<u8> {
    let mut r = ChaCha8Rng::seed_from_u64(seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    (0..size).map(|_| r.gen()).collect()
}

#[derive(Serialize)]
struct Summary {
    link: String,
    messages: usize,
    bytes_per_message: usize,
    delivered: usize,
    failed: usize,
    corrupted: usize,
    retransmissions: u64,
    goodput_bps: f64,
    bound_bps: Option<f64>,
    seconds: f64,
    /// Links a bond dropped on the way.
    links_dropped: Vec<String>,
}

impl Summary {
    fn new(args: &Args, bound_bps: Option<f64>) -> Self {
        Summary {
            link: super::links_name(&args.link),
            messages: args.count,
            bytes_per_message: args.size,
            delivered: 0,
            failed: 0,
            corrupted: 0,
            retransmissions: 0,
            goodput_bps: 0.0,
            bound_bps,
            seconds: 0.0,
            links_dropped: Vec::new(),
        }
    }
}

#[derive(Serialize)]
struct SweepRow {
    loss: f64,
    delivered: bool,
    seconds: f64,
    goodput_bps: f64,
    goodput_of_bound: f64,
    segments: u64,
    retransmissions: u64,
}

/// Runs the test.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let specs = (args.link.iter())
        .map(|l| super::link_spec(l))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let sims: Vec<(SimConfig, f64)> = (specs.iter())
        .filter_map(|s| match s {
            LinkSpec::Sim { config, speedup } => Some((*config, *speedup)),
            _ => None,
        })
        .collect();
    match (&specs[..], &sims[..]) {
        ([_], [(config, _)]) if args.sweep && args.keys => sweep_sealed(*config, &args, out),
        ([_], [(config, _)]) if args.sweep => sweep(*config, &args, out),
        ([_], [(config, _)]) => simulate(*config, &args, out),
        (_, []) => real(&specs, &args, out),
        _ if args.sweep => anyhow::bail!("--sweep takes one --link"),
        _ if sims.len() == specs.len() => bonded(&sims, &args, out),
        _ => anyhow::bail!("a bond's links are all sim: (both ends here) or none (one end here)"),
    }
}

/// Several `sim:` links: one simulated radio pair each, bonded at both
/// ends, in real time sped up by the specs' `speedup`; goodput in radio
/// time (real time × speedup), against the sum of the pairs' bounds.
fn bonded(sims: &[(SimConfig, f64)], args: &Args, out: &super::Output) -> anyhow::Result<()> {
    let speedup = sims[0].1;
    anyhow::ensure!(
        sims.iter().all(|&(_, s)| s == speedup),
        "the sim: links of a bond run at one speedup"
    );
    let configs: Vec<SimConfig> = (sims.iter().enumerate())
        .map(|(i, (c, _))| SimConfig {
            seed: c.seed.wrapping_add(i as u64),
            ..*c
        })
        .collect();
    let (a, b) = Bond::sim_pair(&configs, speedup);
    let rx_args = args.clone();
    let receiver = std::thread::spawn(move || -> anyhow::Result<Summary> {
        let mut ep = Endpoint::new(Box::new(b))?;
        let mut s = Summary::new(&rx_args, None);
        receive_messages(&mut ep, &rx_args, &mut s);
        ep.linger(Duration::from_millis(300))?;
        Ok(s)
    });
    let mut s = Summary::new(args, Some(configs.iter().map(SimConfig::bound_bps).sum()));
    let (mut ep, dropped) = endpoint(Box::new(a), &args.link)?;
    let start = Instant::now();
    send_messages(&mut ep, args, &mut s);
    s.seconds = start.elapsed().as_secs_f64() * speedup;
    let r = (receiver.join()).map_err(|_| anyhow::anyhow!("the receiving end panicked"))??;
    anyhow::ensure!(
        s.delivered <= r.delivered + r.corrupted,
        "the sender counted {} messages delivered, the receiver got {}",
        s.delivered,
        r.delivered + r.corrupted
    );
    (s.delivered, s.corrupted) = (r.delivered, r.corrupted);
    s.links_dropped = dropped.lock().expect("notices").clone();
    finish(s, Role::Send, out)
}

fn simulate(config: SimConfig, args: &Args, out: &super::Output) -> anyhow::Result<()> {
    let mut s = Summary::new(args, Some(config.bound_bps()));
    for i in 0..args.count {
        let msg = test_message(args.seed, i, args.size);
        let cfg = SimConfig {
            seed: config.seed.wrapping_add(i as u64),
            ..config
        };
        let r = sim::transfer(cfg, Config::for_mtu(config.mtu), &msg);
        s.delivered += r.delivered as usize;
        s.failed += (!r.delivered) as usize;
        s.corrupted += r.corrupted as usize;
        s.retransmissions += r.retransmissions;
        s.seconds += r.seconds;
    }
    s.goodput_bps = (s.delivered * args.size) as f64 * 8.0 / s.seconds.max(1e-9);
    print_summary(&s, out)
}

fn print_summary(s: &Summary, out: &super::Output) -> anyhow::Result<()> {
    out.emit(s, || {
        format!(
            "{}: {}/{} messages of {} B delivered, {} failed, {} corrupted; {} retransmissions; goodput {:.1} kb/s{} over {:.2} s\n",
            s.link,
            s.delivered,
            s.messages,
            s.bytes_per_message,
            s.failed,
            s.corrupted,
            s.retransmissions,
            s.goodput_bps / 1e3,
            s.bound_bps.map_or(String::new(), |b| format!(" ({:.1} % of the {:.1} kb/s bound)", 100.0 * s.goodput_bps / b, b / 1e3)),
            s.seconds
        )
    })
}

fn sweep(config: SimConfig, args: &Args, out: &super::Output) -> anyhow::Result<()> {
    let bound = config.bound_bps();
    let msg = test_message(args.seed, 0, args.size);
    let rows: Vec<SweepRow> = SWEEP_LOSSES
        .into_iter()
        .map(|loss| {
            let r = sim::transfer(
                SimConfig { loss, ..config },
                Config::for_mtu(config.mtu),
                &msg,
            );
            SweepRow {
                loss,
                delivered: r.delivered,
                seconds: r.seconds,
                goodput_bps: r.goodput_bps,
                goodput_of_bound: r.goodput_bps / bound,
                segments: r.segments,
                retransmissions: r.retransmissions,
            }
        })
        .collect();
    out.emit(&rows, || {
        let mut s = format!(
            "{} B message over simulated XBee {} at {} baud, {}-byte payloads (bound {:.1} kb/s; \
             the {DATA_OVERHEAD}-byte segment header leaves at most {:.1} % of it)\n \
             loss  delivered  time s  goodput kb/s  of bound  segments  retransmissions\n",
            args.size,
            config.radio,
            config.baud,
            config.mtu,
            bound / 1e3,
            100.0 * (config.mtu - DATA_OVERHEAD) as f64 / config.mtu as f64
        );
        for r in &rows {
            s += &format!(
                "{:4.0} %  {:>9}  {:6.2}  {:12.1}  {:7.1} %  {:8}  {:15}\n",
                r.loss * 100.0,
                r.delivered,
                r.seconds,
                r.goodput_bps / 1e3,
                r.goodput_of_bound * 100.0,
                r.segments,
                r.retransmissions
            );
        }
        s
    })
}

/// The losses every sweep runs.
const SWEEP_LOSSES: [f64; 6] = [0.0, 0.01, 0.05, 0.10, 0.20, 0.30];

#[derive(Serialize)]
struct SealedRow {
    loss: f64,
    seeds: usize,
    delivered_plain: usize,
    delivered_sealed: usize,
    goodput_plain_bps: f64,
    goodput_sealed_bps: f64,
    goodput_loss_percent: f64,
    handshake_median_ms: f64,
    handshake_max_ms: f64,
}

/// The sweep with and without keys, `--count` seeds per loss (the same
/// seeds for both), goodput as message bytes over the mean time.
fn sweep_sealed(config: SimConfig, args: &Args, out: &super::Output) -> anyhow::Result<()> {
    let msg = test_message(args.seed, 0, args.size);
    let arq = Config::for_mtu(config.mtu);
    let seeds = args.count.max(1);
    let bar = super::progress((SWEEP_LOSSES.len() * seeds) as u64, "sweep");
    let rows: Vec<SealedRow> = SWEEP_LOSSES
        .into_iter()
        .map(|loss| {
            let (mut plain, mut sealed, mut hs) = (Vec::new(), Vec::new(), Vec::new());
            for k in 0..seeds as u64 {
                let sim = SimConfig {
                    loss,
                    seed: config.seed.wrapping_add(k),
                    ..config
                };
                plain.push(sim::transfer(sim, arq, &msg));
                let r = sealed_transfer(sim, arq, &msg);
                anyhow::ensure!(
                    !r.message.delivered || r.opened,
                    "a sealed message did not open"
                );
                if r.handshake_done {
                    hs.push(r.handshake_seconds * 1e3);
                }
                sealed.push(r.message);
                bar.inc(1);
            }
            let goodput = |rs: &[sim::TransferReport]| {
                let ok: Vec<_> = rs.iter().filter(|r| r.delivered).collect();
                let secs: f64 = ok.iter().map(|r| r.seconds).sum();
                (
                    ok.len(),
                    ok.len() as f64 * msg.len() as f64 * 8.0 / secs.max(1e-9),
                )
            };
            let ((dp, gp), (ds, gs)) = (goodput(&plain), goodput(&sealed));
            hs.sort_by(f64::total_cmp);
            Ok(SealedRow {
                loss,
                seeds,
                delivered_plain: dp,
                delivered_sealed: ds,
                goodput_plain_bps: gp,
                goodput_sealed_bps: gs,
                goodput_loss_percent: 100.0 * (1.0 - gs / gp.max(1e-9)),
                handshake_median_ms: hs.get(hs.len() / 2).copied().unwrap_or(f64::NAN),
                handshake_max_ms: hs.last().copied().unwrap_or(f64::NAN),
            })
        })
        .collect::<anyhow::Result<_>>()?;
    bar.finish_and_clear();
    out.emit(&rows, || {
        let mut s = format!(
            "{} B message over simulated XBee {} at {} baud, {} seeds per loss, with and without keys\n \
             loss  delivered  goodput kb/s: no keys  keys  loss of goodput  handshake ms: median  max\n",
            args.size, config.radio, config.baud, seeds
        );
        for r in &rows {
            s += &format!(
                "{:4.0} %  {:>3}/{:<3}  {:>24.1}  {:4.1}  {:13.2} %  {:>20.1}  {:4.1}\n",
                r.loss * 100.0,
                r.delivered_sealed,
                r.delivered_plain,
                r.goodput_plain_bps / 1e3,
                r.goodput_sealed_bps / 1e3,
                r.goodput_loss_percent,
                r.handshake_median_ms,
                r.handshake_max_ms
            );
        }
        s
    })
}

fn real(specs: &[LinkSpec], args: &Args, out: &super::Output) -> anyhow::Result<()> {
    let role = args.role.ok_or_else(|| {
        anyhow::anyhow!("a real link needs --role send or --role receive (one process each)")
    })?;
    let mut s = Summary::new(args, None);
    let (mut ep, dropped) = endpoint(spec::open_all(specs)?, &args.link)?;
    let start = Instant::now();
    match role {
        Role::Send => send_messages(&mut ep, args, &mut s),
        Role::Receive => receive_messages(&mut ep, args, &mut s),
    }
    s.seconds = start.elapsed().as_secs_f64();
    if role == Role::Receive {
        // Keep answering retransmissions in case our last ACK was lost.
        ep.linger(Duration::from_millis(500))?;
    }
    s.links_dropped = dropped.lock().expect("notices").clone();
    finish(s, role, out)
}

/// The links a bond dropped, as its endpoint's notices said.
type Dropped = Arc<Mutex<Vec<String>>>;

/// An endpoint over `transport` that says its notices on stderr and lists
/// the links a bond dropped.
fn endpoint(
    transport: Box<dyn stereolink_link::transport::Transport>,
    links: &[String],
) -> anyhow::Result<(Endpoint, Dropped)> {
    let mut ep = Endpoint::new(transport)?;
    let name = super::links_name(links);
    let dropped = Dropped::default();
    let list = dropped.clone();
    ep.on_notice(Box::new(move |notice| {
        eprintln!("link {name}: {notice}");
        if let Notice::MemberDown { member, .. } = notice {
            list.lock().expect("notices").push(member);
        }
    }));
    Ok((ep, dropped))
}

/// Sends the `--count` test messages, counting them in `s`.
fn send_messages(ep: &mut Endpoint, args: &Args, s: &mut Summary) {
    for i in 0..args.count {
        match ep.send_message(&test_message(args.seed, i, args.size)) {
            Ok(st) => {
                s.delivered += 1;
                s.retransmissions += st.retransmissions;
            }
            Err(e) => {
                eprintln!("message {i}: {e}");
                s.failed += 1;
            }
        }
    }
}

/// Receives and checks the `--count` test messages, counting them in `s`.
fn receive_messages(ep: &mut Endpoint, args: &Args, s: &mut Summary) {
    for i in 0..args.count {
        match ep.recv_message(Duration::from_secs(args.timeout_s)) {
            Ok(m) if m == test_message(args.seed, i, args.size) => s.delivered += 1,
            Ok(_) => s.corrupted += 1,
            Err(e) => {
                eprintln!("message {i}: {e}");
                s.failed += 1;
            }
        }
    }
}

/// Prints the summary (goodput over its time) and fails if a message did.
fn finish(mut s: Summary, role: Role, out: &super::Output) -> anyhow::Result<()> {
    s.goodput_bps = (s.delivered * s.bytes_per_message) as f64 * 8.0 / s.seconds.max(1e-9);
    print_summary(&s, out)?;
    anyhow::ensure!(
        s.failed == 0 && s.corrupted == 0,
        "{} failed, {} corrupted ({role:?})",
        s.failed,
        s.corrupted
    );
    Ok(())
}
