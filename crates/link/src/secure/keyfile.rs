//! Key files: one X25519 key per file as a single line of standard base64
//! (44 characters), the format of WireGuard's `wg genkey` and `wg pubkey`,
//! so either tool's keys can be used. `NAME.key` holds the private key and
//! is created with mode 0600; `NAME.pub` the public key.

use std::io::Write;
use std::path::{Path, PathBuf};

use base64::engine::general_purpose::STANDARD;
use base64::Engine;
use rand::rngs::OsRng;
use rand::RngCore;

use super::{public_key, Keys};

/// Why a key file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum KeyFileError {
    /// Reading or writing the file failed.
    #[error("key file {path}: {error}", path = .0.display(), error = .1)]
    Io(PathBuf, std::io::Error),
    /// The file does not hold one base64 32-byte key.
    #[error(
        "key file {} does not hold one base64 32-byte key (make one with `stereolink keygen`)",
        .0.display()
    )]
    Malformed(PathBuf),
    /// The file to write exists already.
    #[error("{} exists already; remove it first to replace the key pair", .0.display())]
    Exists(PathBuf),
}

/// Reads one key from `path`.
pub fn read_key(path: &Path) -> Result<[u8; 32], KeyFileError> {
    let text =
        std::fs::read_to_string(path).map_err(|e| KeyFileError::Io(path.to_path_buf(), e))?;
    let malformed = || KeyFileError::Malformed(path.to_path_buf());
    let bytes = STANDARD.decode(text.trim()).map_err(|_| malformed())?;
    bytes.try_into().map_err(|_| malformed())
}

/// This device's private key file and the peer's public key file.
pub fn read_keys(private: &Path, peer: &Path) -> Result<Keys, KeyFileError> {
    Ok(Keys::new(read_key(private)?, read_key(peer)?))
}

/// The key pair's paths for a `name`: `name.key` and `name.pub`.
pub fn paths(name: &Path) -> (PathBuf, PathBuf) {
    let with = |ext: &str| {
        let mut p = name.as_os_str().to_owned();
        p.push(ext);
        PathBuf::from(p)
    };
    (with(".key"), with(".pub"))
}

/// Draws a key pair from the OS RNG and writes `name.key` (mode 0600) and
/// `name.pub`; refuses to overwrite either.
pub fn generate(name: &Path) -> Result<(PathBuf, PathBuf), KeyFileError> {
    let (key, public) = paths(name);
    for p in [&key, &public] {
        if p.exists() {
            return Err(KeyFileError::Exists(p.clone()));
        }
    }
    let private = random_key().map_err(|e| KeyFileError::Io(key.clone(), e))?;
    write_new(&key, &private, 0o600)?;
    write_new(&public, &public_key(&private), 0o644)?;
    Ok((key, public))
}

/// A private key from the OS RNG.
pub fn random_key() -> std::io::Result<[u8; 32]> {
    let mut private = [0u8; 32];
    OsRng
        .try_fill_bytes(&mut private)
        .map_err(std::io::Error::other)?;
    Ok(private)
}

fn write_new(path: &Path, key: &[u8; 32], mode: u32) -> Result<(), KeyFileError> {
    use std::os::unix::fs::OpenOptionsExt;
    let io = |e| KeyFileError::Io(path.to_path_buf(), e);
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode)
        .open(path)
        .map_err(io)?;
    writeln!(f, "{}", STANDARD.encode(key)).map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_generated_pair_reads_back_private_and_public() {
        let dir = std::env::temp_dir().join(format!("stereolink-keys-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let name = dir.join("robot");
        let (key, public) = generate(&name).unwrap();
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&key).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        assert_eq!(
            public_key(&read_key(&key).unwrap()),
            read_key(&public).unwrap()
        );
        assert!(matches!(generate(&name), Err(KeyFileError::Exists(_))));
        std::fs::write(dir.join("bad.pub"), "not a key\n").unwrap();
        assert!(matches!(
            read_key(&dir.join("bad.pub")),
            Err(KeyFileError::Malformed(_))
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
