//! A camera folder: the stereo pairs that a capture program writes into a
//! directory, found as they arrive, so that `send --watch` can send each
//! new pair once.
//!
//! A pair is a file whose name starts with `left` and the file whose name
//! is the same with `right` in its place (`left_0001.png` and
//! `right_0001.png`, `left.png` and `right.png`). Pairs are taken in the
//! order of their names; a pair whose files are rewritten (a new
//! modification time or size) counts as new again, so a program that
//! overwrites `left.png`/`right.png` is followed too.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// One pair in the folder.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pair {
    /// The part of the names after `left`/`right` (`_0001.png`).
    pub name: String,
    /// The left view's file.
    pub left: PathBuf,
    /// The right view's file.
    pub right: PathBuf,
}

/// What a file looked like when its pair was taken.
type Stamp = (Option<SystemTime>, u64);

/// The pairs of a folder that were not taken yet.
#[derive(Default)]
pub struct Watcher {
    taken: HashMap<String, (Stamp, Stamp)>,
}

fn stamp(path: &Path) -> std::io::Result<Stamp> {
    let meta = std::fs::metadata(path)?;
    Ok((meta.modified().ok(), meta.len()))
}

impl Watcher {
    /// A watcher that has taken nothing yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The complete pairs in `dir` that are new or rewritten since they
    /// were last [taken](Self::take), in name order.
    pub fn pending(&self, dir: &Path) -> std::io::Result<Vec<Pair>> {
        let mut pairs = Vec::new();
        for entry in std::fs::read_dir(dir)? {
            let entry = entry?;
            let file_name = entry.file_name();
            let Some(name) = file_name.to_str().and_then(|n| n.strip_prefix("left")) else {
                continue;
            };
            let (left, right) = (entry.path(), dir.join(format!("right{name}")));
            let (Ok(l), Ok(r)) = (stamp(&left), stamp(&right)) else {
                continue;
            };
            if self.taken.get(name) != Some(&(l, r)) {
                pairs.push(Pair {
                    name: name.to_string(),
                    left,
                    right,
                });
            }
        }
        pairs.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(pairs)
    }

    /// Marks `pair` as taken in its files' present state.
    pub fn take(&mut self, pair: &Pair) -> std::io::Result<()> {
        let stamps = (stamp(&pair.left)?, stamp(&pair.right)?);
        self.taken.insert(pair.name.clone(), stamps);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(pairs: &[Pair]) -> Vec<&str> {
        pairs.iter().map(|p| p.name.as_str()).collect()
    }

    #[test]
    fn finds_complete_pairs_in_order_once() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for f in [
            "left_2.png",
            "right_2.png",
            "left_1.png",
            "right_1.png",
            "left_3.png",
            "notes.txt",
        ] {
            std::fs::write(d.join(f), f).unwrap();
        }
        let mut w = Watcher::new();
        let pending = w.pending(d).unwrap();
        // left_3 has no right view yet.
        assert_eq!(names(&pending), ["_1.png", "_2.png"]);
        assert_eq!(pending[0].right, d.join("right_1.png"));
        for p in &pending {
            w.take(p).unwrap();
        }
        assert!(w.pending(d).unwrap().is_empty());
        std::fs::write(d.join("right_3.png"), "r").unwrap();
        assert_eq!(names(&w.pending(d).unwrap()), ["_3.png"]);
    }

    #[test]
    fn a_rewritten_pair_is_new_again() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("left.png"), "a").unwrap();
        std::fs::write(d.join("right.png"), "b").unwrap();
        let mut w = Watcher::new();
        w.take(&w.pending(d).unwrap()[0]).unwrap();
        assert!(w.pending(d).unwrap().is_empty());
        std::fs::write(d.join("left.png"), "a longer file").unwrap();
        assert_eq!(names(&w.pending(d).unwrap()), [".png"]);
    }

    #[test]
    fn a_missing_folder_is_an_error() {
        assert!(Watcher::new()
            .pending(Path::new("/no/such/folder"))
            .is_err());
    }
}
