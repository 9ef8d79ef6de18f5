//! The certificate store of an anonymous-only server: it has none, and needs none.
//!
//! async-opcua 0.19 opens a certificate store at `pki_dir` whatever the endpoints (it creates
//! `trusted/` and `rejected/` there) and reads the server's own certificate from it at start and
//! again for every secure channel, logging an ERROR (`opcua_crypto::certificate_store`,
//! `opcua_core::comms::secure_channel`) and a WARN (`opcua_server::server`) each time there is
//! none. With only the unencrypted endpoint (SecurityPolicy None) no certificate is ever used
//! (async-opcua signs and validates nothing on None channels and sessions), so those lines are
//! false and the folder is waste. [`build_without_store`] gives the builder a private temporary
//! folder, removes it before the server runs, and marks those reports false for this process
//! ([`super::is_false_certificate_report`], which the binary's log filter consults).

use std::sync::atomic::Ordering;

use opcua::server::{Server, ServerBuilder, ServerHandle};

/// Build `b` (anonymous only: no user, no encrypted endpoint) with a store that exists only
/// while it is built.
pub(super) fn build_without_store(b: ServerBuilder) -> Result<(Server, ServerHandle), String> {
    let dir = tempfile::Builder::new()
        .prefix("retrocomp-opcua-pki-")
        .tempdir()
        .map_err(|e| format!("creating a temporary certificate folder: {e}"))?;
    super::NO_CERTIFICATE_NEEDED.store(true, Ordering::Relaxed);
    let built = b.pki_dir(dir.path()).build();
    // Removed now: nothing reads the store of a SecurityPolicy None endpoint but to find it empty.
    drop(dir);
    built
}
