//! Where the send loop's pairs come from: one pair of files sent again and
//! again, the pairs a capture program writes into a folder, a recorded
//! sequence played at a camera's rate, or two live cameras.
//!
//! The live sources (a folder, a sequence, cameras) give the newest complete
//! pair each time they are asked, and count the pairs passed over: a sender
//! that matches and sends slower than the camera delivers must act on what
//! the camera sees now, not on a backlog.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, UNIX_EPOCH};

use anyhow::Context;
use stereolink_capture::StereoCapture;
use stereolink_codec::control::unix_us;
use stereolink_image::{io, RgbImage};

use crate::watch::{Pair, Watcher};

/// A pair to send, and what getting it cost.
pub struct Next {
    /// The left view.
    pub left: RgbImage,
    /// The right view.
    pub right: RgbImage,
    /// When it was captured, µs since the Unix epoch (its messages' time
    /// stamp, from which the receiver measures latency).
    pub captured_us: u64,
    /// Time spent waiting for the pair (reading it, or for the cameras), ms.
    pub wait_ms: f64,
    /// Pairs passed over for this newer one.
    pub skipped: u64,
}

/// What [`Pairs::take`] found.
pub enum Got {
    /// A pair.
    Pair(Next),
    /// Nothing yet (a folder with no new pair): ask again.
    Wait,
    /// No more pairs.
    End,
}

/// Where the pairs come from; the send loop is the same for all.
pub struct Pairs(Source);

enum Source {
    /// One pair of files, sent `remaining` more times.
    Files {
        left: RgbImage,
        right: RgbImage,
        remaining: u32,
    },
    /// Each new pair a capture program writes into `dir`, read every `poll`.
    Folder {
        dir: PathBuf,
        poll: Duration,
        watcher: Watcher,
    },
    /// Recorded pairs, pair `k` captured at `start + k × period`.
    Sequence {
        pairs: Vec<(RgbImage, RgbImage)>,
        period: Duration,
        start: Option<(Instant, u64)>,
        taken: Option<usize>,
    },
    /// Two live cameras; `skipped` is their count at the last pair.
    Cameras {
        capture: Box<StereoCapture>,
        timeout: Duration,
        skipped: u64,
    },
}

impl Pairs {
    /// One pair of files, sent `repeat` times; every one is a frame.
    pub fn files(left: RgbImage, right: RgbImage, repeat: u32) -> Pairs {
        Pairs(Source::Files {
            left,
            right,
            remaining: repeat,
        })
    }

    /// Each new pair a capture program writes into `dir` (`left*.png` with
    /// the `right*.png` of the same name; a rewritten pair is new again),
    /// the folder read every `poll`. The newest in name order wins; older
    /// new ones are skipped, and so is one that cannot be read (half
    /// written, or views of different sizes) until its files change.
    pub fn folder(dir: PathBuf, poll: Duration) -> Pairs {
        Pairs(Source::Folder {
            dir,
            poll,
            watcher: Watcher::new(),
        })
    }

    /// The pairs of a folder (`left*.png` and `right*.png`, in name order)
    /// played as a camera at `rate_hz`, from the first call to
    /// [`Pairs::take`]: `bench live`'s input.
    pub fn sequence(dir: &Path, rate_hz: f64) -> anyhow::Result<Pairs> {
        anyhow::ensure!(
            rate_hz.is_finite() && rate_hz > 0.0 && rate_hz <= 1000.0,
            "the rate must be between 0 and 1000 pairs a second (got {rate_hz})"
        );
        let found = Watcher::new()
            .pending(dir)
            .with_context(|| format!("cannot read the sequence folder {}", dir.display()))?;
        anyhow::ensure!(
            !found.is_empty(),
            "{} holds no pairs (left*.png with right*.png of the same name)",
            dir.display()
        );
        let mut pairs = Vec::with_capacity(found.len());
        for p in &found {
            let left = io::read_rgb(&p.left)
                .with_context(|| format!("cannot read {}", p.left.display()))?;
            let right = io::read_rgb(&p.right)
                .with_context(|| format!("cannot read {}", p.right.display()))?;
            anyhow::ensure!(
                left.dims() == right.dims(),
                "{}: the views differ in size",
                p.left.display()
            );
            pairs.push((left, right));
        }
        Ok(Pairs(Source::Sequence {
            pairs,
            period: Duration::from_secs_f64(1.0 / rate_hz),
            start: None,
            taken: None,
        }))
    }

    /// Two live cameras; one that delivers nothing for `timeout` stops the
    /// loop with an error.
    pub fn cameras(timeout: Duration, capture: StereoCapture) -> Pairs {
        Pairs(Source::Cameras {
            timeout,
            capture: Box::new(capture),
            skipped: 0,
        })
    }

    /// Whether the pairs come live from cameras (the next one is always
    /// fresh, and comes at once).
    pub fn cameras_live(&self) -> bool {
        matches!(self.0, Source::Cameras { .. })
    }

    /// Whether the pairs come at the camera's pace, each newer than the
    /// last: then each pair gets a depth report, and a frame only when the
    /// link has finished the one before.
    pub fn paced(&self) -> bool {
        !matches!(self.0, Source::Files { .. })
    }

    /// The next pair, [`Got::Wait`] after one poll interval of an empty
    /// folder (a folder is waited on forever), or [`Got::End`]. A camera
    /// that stops is an error.
    pub fn take(&mut self) -> anyhow::Result<Got> {
        let start = Instant::now();
        let wait_ms = || start.elapsed().as_secs_f64() * 1e3;
        match &mut self.0 {
            Source::Files {
                left,
                right,
                remaining,
            } => {
                if *remaining == 0 {
                    return Ok(Got::End);
                }
                *remaining -= 1;
                Ok(Got::Pair(Next {
                    left: left.clone(),
                    right: right.clone(),
                    captured_us: unix_us(),
                    wait_ms: wait_ms(),
                    skipped: 0,
                }))
            }
            Source::Folder { dir, poll, watcher } => {
                let mut pending = watcher
                    .pending(dir)
                    .with_context(|| format!("cannot read the camera folder {}", dir.display()))?;
                let mut skipped = 0;
                while let Some(pair) = pending.pop() {
                    if let Some((left, right)) = read_pair(watcher, &pair)? {
                        // The older new pairs are passed over for good.
                        for old in pending.drain(..) {
                            watcher
                                .take(&old)
                                .with_context(|| format!("cannot read {}", old.left.display()))?;
                            skipped += 1;
                        }
                        return Ok(Got::Pair(Next {
                            left,
                            right,
                            captured_us: written_us(&pair),
                            wait_ms: wait_ms(),
                            skipped,
                        }));
                    }
                    skipped += 1;
                }
                std::thread::sleep(*poll);
                Ok(Got::Wait)
            }
            Source::Sequence {
                pairs,
                period,
                start,
                taken,
            } => {
                let (t0, t0_us) = *start.get_or_insert_with(|| (Instant::now(), unix_us()));
                let newest = |now: Instant| {
                    let k = now.duration_since(t0).as_secs_f64() / period.as_secs_f64();
                    (k.floor() as usize).min(pairs.len() - 1)
                };
                let first = taken.map_or(0, |t| t + 1);
                if first >= pairs.len() {
                    return Ok(Got::End);
                }
                // Wait for the camera to deliver the next pair.
                let due = t0 + period.mul_f64(first as f64);
                std::thread::sleep(due.saturating_duration_since(Instant::now()));
                let k = newest(Instant::now()).max(first);
                *taken = Some(k);
                let (left, right) = pairs[k].clone();
                let offset = period.mul_f64(k as f64).as_micros() as u64;
                Ok(Got::Pair(Next {
                    left,
                    right,
                    captured_us: t0_us + offset,
                    wait_ms: wait_ms(),
                    skipped: (k - first) as u64,
                }))
            }
            Source::Cameras {
                capture,
                timeout,
                skipped,
            } => {
                let pair = capture.next_pair(*timeout)?;
                let new = pair.stats.skipped - *skipped;
                *skipped = pair.stats.skipped;
                Ok(Got::Pair(Next {
                    left: pair.left,
                    right: pair.right,
                    captured_us: unix_us(),
                    wait_ms: wait_ms(),
                    skipped: new,
                }))
            }
        }
    }
}

/// When a folder's pair was written: its newer file's modification time
/// (the capture program writes it right after capturing), or now.
fn written_us(pair: &Pair) -> u64 {
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    let newest = modified(&pair.left).max(modified(&pair.right));
    let now = unix_us();
    newest
        .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
        .map_or(now, |d| (d.as_micros() as u64).min(now))
}

/// Takes a folder's pair and reads it; a pair that cannot be read (a file
/// half written, views of different sizes) is reported and skipped until
/// its files change.
fn read_pair(watcher: &mut Watcher, pair: &Pair) -> anyhow::Result<Option<(RgbImage, RgbImage)>> {
    watcher
        .take(pair)
        .with_context(|| format!("cannot read {}", pair.left.display()))?;
    let views = io::read_rgb(&pair.left).and_then(|l| Ok((l, io::read_rgb(&pair.right)?)));
    match views {
        Ok(views) if views.0.dims() == views.1.dims() => Ok(Some(views)),
        Ok(_) => {
            eprintln!("skipping {}: the views differ in size", pair.left.display());
            Ok(None)
        }
        Err(e) => {
            eprintln!(
                "skipping {}: {:#}",
                pair.left.display(),
                anyhow::Error::from(e)
            );
            Ok(None)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_pair(dir: &Path, name: &str, shade: u8) {
        let img = RgbImage::from_fn(8, 6, |_, _| [shade; 3]);
        io::write_rgb(dir.join(format!("left{name}")), &img).unwrap();
        io::write_rgb(dir.join(format!("right{name}")), &img).unwrap();
    }

    fn shade(got: Got) -> (u8, u64) {
        match got {
            Got::Pair(n) => (n.left.get(0, 0)[0], n.skipped),
            Got::Wait => (0, u64::MAX),
            Got::End => (255, u64::MAX),
        }
    }

    #[test]
    fn a_folder_gives_its_newest_pair_and_counts_the_rest() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for (i, s) in [(1, 10), (2, 20), (3, 30)] {
            write_pair(d, &format!("_{i}.png"), s);
        }
        // The newest is half written: the one before it wins.
        std::fs::write(d.join("left_4.png"), b"half a png").unwrap();
        std::fs::write(d.join("right_4.png"), b"").unwrap();
        let mut pairs = Pairs::folder(d.to_path_buf(), Duration::from_millis(1));
        assert_eq!(shade(pairs.take().unwrap()), (30, 3));
        assert!(matches!(pairs.take().unwrap(), Got::Wait));
        // Rewritten whole, the half-written pair comes.
        write_pair(d, "_4.png", 40);
        assert_eq!(shade(pairs.take().unwrap()), (40, 0));
    }

    #[test]
    fn a_sequence_plays_at_its_rate_and_a_slow_taker_skips() {
        let dir = tempfile::tempdir().unwrap();
        for i in 0..6u8 {
            write_pair(dir.path(), &format!("_{i}.png"), i * 10 + 1);
        }
        let mut pairs = Pairs::sequence(dir.path(), 50.0).unwrap();
        let t0 = Instant::now();
        assert_eq!(shade(pairs.take().unwrap()), (1, 0));
        // 65 ms later, pairs 1 to 3 at least have come (one every 20 ms):
        // the newest wins, the others are counted.
        std::thread::sleep(Duration::from_millis(65));
        let (mut last, skipped) = shade(pairs.take().unwrap());
        assert!(
            skipped >= 2 && last == 10 * (skipped as u8 + 1) + 1,
            "{last} {skipped}"
        );
        let mut seen = 2 + skipped;
        loop {
            match pairs.take().unwrap() {
                Got::Pair(n) => {
                    let s = n.left.get(0, 0)[0];
                    assert_eq!(s, last + 10 * (n.skipped as u8 + 1));
                    (last, seen) = (s, seen + 1 + n.skipped);
                }
                Got::Wait => panic!("a sequence never waits"),
                Got::End => break,
            }
        }
        // Every pair was taken or counted, none before its time.
        assert_eq!((last, seen), (51, 6));
        assert!(t0.elapsed() >= Duration::from_millis(80));
    }

    #[test]
    fn an_empty_sequence_or_a_bad_rate_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        assert!(Pairs::sequence(dir.path(), 10.0).is_err());
        write_pair(dir.path(), ".png", 1);
        assert!(Pairs::sequence(dir.path(), 0.0).is_err());
        assert!(Pairs::sequence(dir.path(), f64::NAN).is_err());
    }
}
