//! TLS to the broker (`mqtts://`): the rustls client configuration built
//! from the operator's PEM files, with ring as the crypto provider, passed
//! explicitly (no process-wide default, no aws-lc or OpenSSL C build), and
//! the one-line cause of a TLS failure, so that a wrong CA, an expired
//! certificate or a plaintext port is said plainly at the first connect
//! instead of being retried for ever.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::{CertificateError, ClientConfig, RootCertStore};

/// The files of a TLS connection to the broker.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TlsFiles {
    /// PEM certificates of the CAs the broker's certificate must chain to
    /// (the system's CAs when `None`).
    pub ca: Option<PathBuf>,
    /// The gateway's own certificate chain and private key (PEM), for a
    /// broker that asks for client certificates (mutual TLS).
    pub client: Option<(PathBuf, PathBuf)>,
}

/// Builds the rustls client configuration: the CAs to trust, the client
/// certificate if any, TLS 1.2 and 1.3 through ring.
pub fn client_config(files: &TlsFiles) -> anyhow::Result<Arc<ClientConfig>> {
    let mut roots = RootCertStore::empty();
    match &files.ca {
        Some(path) => {
            let certs = certificates(path, "--mqtt-ca")?;
            let (added, _) = roots.add_parsable_certificates(certs);
            anyhow::ensure!(
                added > 0,
                "--mqtt-ca {}: no usable CA certificate in it",
                path.display()
            );
        }
        None => {
            let found = rustls_native_certs::load_native_certs();
            roots.add_parsable_certificates(found.certs);
            anyhow::ensure!(
                !roots.is_empty(),
                "mqtts:// without --mqtt-ca needs the system's CA certificates, and none \
                 were found ({} error(s)); give the broker's CA with --mqtt-ca",
                found.errors.len()
            );
        }
    }
    // rustls 0.23.48 deprecates ring's provider for its lack of post-quantum
    // key exchange, which only aws-lc (a C build) offers; X25519 and the
    // NIST curves are what Debian's Mosquitto (OpenSSL 3.0) negotiates.
    #[allow(deprecated)]
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("the TLS provider offers no safe protocol version")?
        .with_root_certificates(roots);
    let config = match &files.client {
        Some((cert, key)) => {
            let chain = certificates(cert, "--mqtt-cert")?;
            let private = PrivateKeyDer::from_pem_file(key).map_err(|e| {
                anyhow::anyhow!("--mqtt-key {}: no private key read: {e}", key.display())
            })?;
            builder
                .with_client_auth_cert(chain, private)
                .with_context(|| {
                    format!(
                        "--mqtt-cert {} with --mqtt-key {}",
                        cert.display(),
                        key.display()
                    )
                })?
        }
        None => builder.with_no_client_auth(),
    };
    Ok(Arc::new(config))
}

/// Every PEM certificate in `path` (at least one), for `flag`'s error.
fn certificates(path: &Path, flag: &str) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let certs = CertificateDer::pem_file_iter(path)
        .and_then(|it| it.collect::<Result<Vec<_>, _>>())
        .map_err(|e| anyhow::anyhow!("{flag} {}: {e}", path.display()))?;
    anyhow::ensure!(
        !certs.is_empty(),
        "{flag} {}: no PEM certificate in it",
        path.display()
    );
    Ok(certs)
}

/// The cause of a failed connection when TLS is what failed (the
/// handshake, the broker's certificate, a client certificate the broker
/// wanted), in a few words; `None` for anything else (a refused or lost
/// TCP connection, a refused login). `handshake`: the error's TLS variant,
/// if it is one (either protocol version's client has one).
pub fn failure(
    e: &(dyn std::error::Error + 'static),
    handshake: Option<&rumqttc::TlsError>,
) -> Option<String> {
    if let Some(r) = rustls_error(e) {
        return Some(explain(r));
    }
    handshake.map(|t| match t {
        // Only the handshake reports I/O as TLS errors: the TCP
        // connection was made, and then cut (a plaintext port resets it).
        rumqttc::TlsError::Io(io) => {
            format!("the TLS handshake was cut off: is that port a TLS listener? ({io})")
        }
        other => other.to_string(),
    })
}

/// The rustls error at the root of `e`, if any: rustls's errors travel
/// inside I/O errors, which do not list them as their source.
fn rustls_error<'a>(e: &'a (dyn std::error::Error + 'static)) -> Option<&'a rustls::Error> {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if let Some(r) = err.downcast_ref::<rustls::Error>() {
            return Some(r);
        }
        if let Some(inner) = err
            .downcast_ref::<std::io::Error>()
            .and_then(|io| io.get_ref())
        {
            if let Some(r) = inner.downcast_ref::<rustls::Error>() {
                return Some(r);
            }
        }
        cur = err.source();
    }
    None
}

/// What a rustls error means for the operator, with rustls's own words.
fn explain(r: &rustls::Error) -> String {
    let meaning = match r {
        rustls::Error::InvalidCertificate(c) => match c {
            // BadSignature: an issuer of the same name, another key.
            CertificateError::UnknownIssuer | CertificateError::BadSignature => {
                "its certificate is not signed by a CA the gateway trusts (--mqtt-ca)"
            }
            CertificateError::Expired | CertificateError::ExpiredContext { .. } => {
                "its certificate has expired"
            }
            CertificateError::NotValidYet | CertificateError::NotValidYetContext { .. } => {
                "its certificate is not valid yet"
            }
            CertificateError::NotValidForName | CertificateError::NotValidForNameContext { .. } => {
                "its certificate is not for this host name"
            }
            _ => "its certificate is refused",
        },
        rustls::Error::AlertReceived(
            rustls::AlertDescription::CertificateRequired
            | rustls::AlertDescription::BadCertificate
            | rustls::AlertDescription::UnknownCA
            | rustls::AlertDescription::CertificateUnknown,
        ) => "it refused the gateway's client certificate, or wanted one (--mqtt-cert, --mqtt-key)",
        rustls::Error::InvalidMessage(_) => "it does not speak TLS on that port",
        _ => "the TLS handshake failed",
    };
    format!("{meaning} ({r})")
}
