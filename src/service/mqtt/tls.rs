//! TLS to the broker: rustls with the ring provider, trusting `ca_file` (else the system's
//! roots), and the broker's certificate checked against its host name.

use rustls::pki_types::CertificateDer;
use rustls::{ClientConfig, RootCertStore};
use std::path::Path;
use std::sync::Arc;

/// Why TLS cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// The CA file cannot be read.
    #[error("ca_file {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// It holds no certificate that rustls takes.
    #[error("ca_file {path}: no PEM certificate in it ({why})")]
    NoCertificate {
        /// The file.
        path: String,
        /// Why.
        why: String,
    },
    /// The system has no root certificates and no ca_file was given.
    #[error("no ca_file given and the system has no root certificates")]
    NoRoots,
    /// rustls refused the setup.
    #[error("TLS setup: {0}")]
    Setup(String),
}

/// The client configuration for a broker whose certificate `ca_file` (or the system) vouches
/// for.
pub fn client_config(ca_file: Option<&Path>) -> Result<Arc<ClientConfig>, TlsError> {
    let mut roots = RootCertStore::empty();
    match ca_file {
        Some(path) => {
            let shown = path.display().to_string();
            let pem = std::fs::read(path).map_err(|source| TlsError::Read {
                path: shown.clone(),
                source,
            })?;
            let certs: Vec<CertificateDer<'static>> = rustls_pemfile::certs(&mut pem.as_slice())
                .collect::<Result<_, _>>()
                .map_err(|e| TlsError::NoCertificate {
                    path: shown.clone(),
                    why: e.to_string(),
                })?;
            let (added, _) = roots.add_parsable_certificates(certs);
            if added == 0 {
                return Err(TlsError::NoCertificate {
                    path: shown,
                    why: "none parses as an X.509 certificate".into(),
                });
            }
        }
        None => {
            let found = rustls_native_certs::load_native_certs();
            roots.add_parsable_certificates(found.certs);
            if roots.is_empty() {
                return Err(TlsError::NoRoots);
            }
        }
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| TlsError::Setup(e.to_string()))?
        .with_root_certificates(roots)
        .with_no_client_auth();
    Ok(Arc::new(config))
}
