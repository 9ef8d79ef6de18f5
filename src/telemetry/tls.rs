//! TLS for the MQTT link: a rustls client config (ring provider, no process-wide default needed)
//! from the PEM files of `[telemetry.mqtt.tls]`: the CA that signed the broker's certificate, and
//! optionally a client certificate and key for brokers that authenticate boxes by certificate.

use anyhow::Context as _;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};

use super::config::TlsConfig;

pub fn client_config(t: &TlsConfig) -> anyhow::Result<rustls::ClientConfig> {
    let mut roots = rustls::RootCertStore::empty();
    let cas = CertificateDer::pem_file_iter(&t.ca_file)
        .with_context(|| format!("telemetry.mqtt.tls.ca_file {}", t.ca_file.display()))?;
    for ca in cas {
        let ca =
            ca.with_context(|| format!("telemetry.mqtt.tls.ca_file {}", t.ca_file.display()))?;
        roots
            .add(ca)
            .with_context(|| format!("telemetry.mqtt.tls.ca_file {}", t.ca_file.display()))?;
    }
    anyhow::ensure!(
        !roots.is_empty(),
        "telemetry.mqtt.tls.ca_file {}: expected at least one PEM certificate",
        t.ca_file.display()
    );
    let provider = std::sync::Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS protocol versions")?
        .with_root_certificates(roots);
    let cfg = match (&t.client_cert_file, &t.client_key_file) {
        (Some(c), Some(k)) => {
            let chain = CertificateDer::pem_file_iter(c)
                .and_then(|it| it.collect::<Result<Vec<_>, _>>())
                .with_context(|| format!("telemetry.mqtt.tls.client_cert_file {}", c.display()))?;
            let key = PrivateKeyDer::from_pem_file(k)
                .with_context(|| format!("telemetry.mqtt.tls.client_key_file {}", k.display()))?;
            builder
                .with_client_auth_cert(chain, key)
                .context("telemetry.mqtt.tls: client certificate and key do not match")?
        }
        _ => builder.with_no_client_auth(),
    };
    Ok(cfg)
}
