//! rustls-webpki 0.103 under the 0.102 name (see Cargo.toml): rumqttc 0.25 names `webpki::Error`
//! in its TLS error type and calls nothing else of the crate.
pub use webpki::*;
