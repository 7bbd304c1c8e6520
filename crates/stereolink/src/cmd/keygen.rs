//! `stereolink keygen`: a device's static key pair for the secure link, and
//! the `--key`/`--peer-key`/`--insecure` arguments `send` and `receive` share.

use std::path::PathBuf;

use anyhow::Context;
use stereolink_link::secure::{keyfile, Keys};

/// Arguments of `stereolink keygen`.
#[derive(Debug, clap::Args)]
#[command(after_long_help = "\
Pairing a sender and a robot (each device keeps its .key, the peers swap .pub):
  stereolink keygen -o sender        # on the sender: sender.key, sender.pub
  stereolink keygen -o robot         # on the board:  robot.key, robot.pub
  # copy sender.pub to the board and robot.pub to the sender, then
  stereolink receive --link ... --robot grbl:/dev/ttyACM0 --key robot.key --peer-key sender.pub
  stereolink send --link ... --left L.png --right R.png --key sender.key --peer-key robot.pub

The files hold one base64 X25519 key each, as WireGuard's `wg genkey | tee K | wg pubkey`
writes them. NAME.key is created with mode 0600 and is never overwritten.")]
pub struct Args {
    /// Name of the pair: writes NAME.key (private, mode 0600) and NAME.pub.
    #[arg(short, long, value_name = "NAME")]
    pub out: PathBuf,
}

/// Writes a new key pair.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let (key, public) = keyfile::generate(&args.out)?;
    out.emit(
        &serde_json::json!({ "private": key, "public": public }),
        || {
            format!(
                "wrote {} (private, keep it on this device) and {} (give it to the peer)\n",
                key.display(),
                public.display()
            )
        },
    )
}

/// The keys of the secure link, as `send` and `receive` take them.
#[derive(Debug, clap::Args)]
pub struct KeyArgs {
    /// This device's private key (NAME.key from `stereolink keygen`).
    #[arg(long, value_name = "FILE", requires = "peer_key")]
    pub key: Option<PathBuf>,
    /// The paired device's public key (its NAME.pub); only it is accepted.
    #[arg(long, value_name = "FILE", requires = "key")]
    pub peer_key: Option<PathBuf>,
    /// Run without keys: nothing received is authenticated, so anyone in
    /// radio range can send frames and reports (and move the axis).
    #[arg(long, conflicts_with_all = ["key", "peer_key"])]
    pub insecure: bool,
}

impl KeyArgs {
    /// The paired keys; without keys, refuses when `moves` (an axis would
    /// obey anyone) unless `--insecure`, and says what that means.
    pub fn load(&self, moves: bool) -> anyhow::Result<Option<Keys>> {
        let (Some(key), Some(peer)) = (&self.key, &self.peer_key) else {
            anyhow::ensure!(
                !moves || self.insecure,
                "refusing to drive the axis over an unauthenticated link: give \
                 --key FILE --peer-key FILE (make them with `stereolink keygen`), \
                 or --insecure to accept that anyone in radio range can move it"
            );
            eprintln!(
                "warning: no --key/--peer-key: the link is not authenticated; anyone in \
                 radio range can send frames and reports{}",
                if moves { " and move the axis" } else { "" }
            );
            return Ok(None);
        };
        let keys = keyfile::read_keys(key, peer).context("cannot load the link keys")?;
        Ok(Some(keys))
    }
}
