//! TLS for the MQTT link: a rustls client config (ring provider, no process-wide default needed)
//! from the PEM files of `[telemetry.mqtt.tls]`: the CA that signed the broker's certificate, and
//! optionally a client certificate and key for brokers that authenticate boxes by certificate.

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};

use super::TelemetryError;
use super::config::TlsConfig;

/// The rustls client config of `t` (also the fleet host's, `retrocomp fleet --tls-ca-file`).
pub fn client_config(t: &TlsConfig) -> Result<rustls::ClientConfig, TelemetryError> {
    let ca_key = || format!("telemetry.mqtt.tls.ca_file {}", t.ca_file.display());
    let mut roots = rustls::RootCertStore::empty();
    let cas = CertificateDer::pem_file_iter(&t.ca_file).map_err(TelemetryError::setup(ca_key()))?;
    for ca in cas {
        let ca = ca.map_err(TelemetryError::setup(ca_key()))?;
        roots.add(ca).map_err(TelemetryError::setup(ca_key()))?;
    }
    if roots.is_empty() {
        return Err(TelemetryError::Invalid(format!(
            "{}: expected at least one PEM certificate",
            ca_key()
        )));
    }
    let provider = std::sync::Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(TelemetryError::setup("TLS protocol versions"))?
        .with_root_certificates(roots);
    let cfg = match (&t.client_cert_file, &t.client_key_file) {
        (Some(c), Some(k)) => {
            let chain = CertificateDer::pem_file_iter(c)
                .and_then(|it| it.collect::<Result<Vec<_>, _>>())
                .map_err(TelemetryError::setup(format!(
                    "telemetry.mqtt.tls.client_cert_file {}",
                    c.display()
                )))?;
            let key = PrivateKeyDer::from_pem_file(k).map_err(TelemetryError::setup(format!(
                "telemetry.mqtt.tls.client_key_file {}",
                k.display()
            )))?;
            builder
                .with_client_auth_cert(chain, key)
                .map_err(TelemetryError::setup(
                    "telemetry.mqtt.tls: client certificate and key do not match",
                ))?
        }
        _ => builder.with_no_client_auth(),
    };
    Ok(cfg)
}
