//! OPC UA server for the plant's systems (MES/SCADA): the box's state as an OPC UA address space,
//! after the companion specifications OPC 40501-1 (Machine Tools) and OPC 40001-1 (Machinery),
//! whose nodesets it imports: the box is a `MachineToolType` in Machinery's `Machines` folder with
//! `Identification` (nameplate from `[opcua.identification]`), `Monitoring`, `Notification` and
//! `Production` (see docs/gateway.md, "OPC UA"). Each value's StatusCode follows its channel's
//! health, its SourceTimestamp is the reading's time. Each fault's start and clear is an
//! `AlarmConditionType` event on the machine object (OPC UA Part 9).
//!
//! It runs on its own tokio tasks fed from the status watch channel (at most 10 updates a second);
//! it never touches the cycle and cannot block it. Everything is read-only for every user: the
//! actions that change the machine go through the token-guarded HTTP API.
//!
//! Units and signs as in `/status`: corrections in µm (correction = −error), positions in mm,
//! sensor values in their channel's unit (the suffix of its name: `_C`, `_mm`, `_N`, …); each
//! analog value carries its `EngineeringUnits` (UNECE codes, e.g. `4H` for µm).
//!
//! This file holds the `[opcua]` section of the field config and its start-time checks;
//! `space.rs` maps a status snapshot to nodes (sans-IO), `server.rs` is the async-opcua shell,
//! `nodesets.rs` the companion nodesets, `instance.rs` the typed machine object, `alarms.rs` the
//! faults' Alarms & Conditions events, `pki.rs` the
//! certificate store an anonymous-only server does without.

#[cfg(feature = "opcua")]
mod alarms;
#[cfg(feature = "opcua")]
mod instance;
#[cfg(feature = "opcua")]
mod nodesets;
#[cfg(feature = "opcua")]
mod pki;
#[cfg(feature = "opcua")]
mod server;
#[cfg(feature = "opcua")]
pub(crate) mod space;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

#[cfg(feature = "opcua")]
pub use server::{OpcUaError, OpcUaServer, start};

/// Set when this process's OPC UA server is anonymous only: it has no certificate and needs none.
static NO_CERTIFICATE_NEEDED: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

/// async-opcua's reports of a missing own certificate, when they are false: the server is
/// anonymous only (SecurityPolicy None), so no certificate is used (see `pki.rs`). The binary's
/// log filter drops these; every other ERROR and WARN passes. Matched by callsite (file and line
/// in async-opcua 0.19.0, which Cargo.lock pins): after an upgrade that moves them they show
/// again (and tests/real_peers/gateway_opcua.rs fails) rather than anything else being hidden.
pub fn is_false_certificate_report(m: &tracing::Metadata<'_>) -> bool {
    const CALLSITES: [(&str, u32); 5] = [
        // "Failed to get cert and private key" / "… cert or private key" (store opened at start)
        ("opcua_crypto::certificate_store", 109),
        ("opcua_crypto::certificate_store", 113),
        // "Failed to read own certificate" / "… private key" (every secure channel)
        ("opcua_core::comms::secure_channel", 127),
        ("opcua_core::comms::secure_channel", 134),
        // "Server is missing its application instance certificate …"
        ("opcua_server::server", 135),
    ];
    let at = (m.target(), m.line().unwrap_or(0));
    CALLSITES.contains(&at) && NO_CERTIFICATE_NEEDED.load(std::sync::atomic::Ordering::Relaxed)
}

/// `[opcua]` of the field config. Absent → no OPC UA server.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpcUaSection {
    /// Address to listen on, `ip:port`; loopback unless you mean otherwise (port 0: any free one).
    #[serde(default = "default_listen")]
    pub listen: String,
    /// Host name clients use in the endpoint URL (`opc.tcp://<host>:<port>/`); default: the listen IP.
    #[serde(default)]
    pub host: Option<String>,
    /// Allow anonymous (read-only) sessions; default: true without `users`, false with.
    #[serde(default)]
    pub anonymous: Option<bool>,
    /// User/password accounts (read-only like everyone). Passwords travel only over the encrypted
    /// endpoint (Basic256Sha256, SignAndEncrypt), which needs `pki_dir`.
    #[serde(default)]
    pub users: Vec<OpcUaUser>,
    /// Users who log in with an X.509 certificate (an OPC UA X509IdentityToken, signed with the
    /// certificate's private key) instead of a password; same endpoint, same read-only rights.
    #[serde(default)]
    pub cert_users: Vec<OpcUaCertUser>,
    /// The server's certificate store (`own/`, `private/`, `trusted/`, `rejected/`); a self-signed
    /// certificate is created there at first start. Relative to the field config. Required with `users`.
    #[serde(default)]
    pub pki_dir: Option<PathBuf>,
    /// Accept any client certificate on the encrypted endpoint (otherwise a client's certificate
    /// must be moved from `pki_dir/rejected` to `pki_dir/trusted` once).
    #[serde(default)]
    pub trust_client_certs: bool,
    /// The listener policy (`retrocomp_bus::listen`): connection caps, idle timeout, descriptor reserve.
    /// Nothing is writable over OPC UA, so `allow_writes_from` has nothing to allow here.
    #[serde(default)]
    pub listen_policy: retrocomp_bus::listen::ListenPolicy,
    /// The machine tool the box compensates, as OPC 40501-1 identifies it (`Identification`).
    /// Required: its three mandatory properties have no default a plant could rely on.
    #[serde(default)]
    pub identification: Option<Identification>,
}

/// `[opcua.identification]`: the machine tool's `MachineToolIdentificationType` properties. The
/// first three are mandatory in OPC 40501-1 / OPC 40001-1; the others are shown when given.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Identification {
    /// `Manufacturer`: the machine tool's maker, as its nameplate says.
    pub manufacturer: Option<String>,
    /// `SerialNumber`: unique among the manufacturer's machines.
    pub serial_number: Option<String>,
    /// `ProductInstanceUri`: globally unique, e.g. `https://maker.example/machines/<serial>`.
    pub product_instance_uri: Option<String>,
    /// `Model`: the machine's model name.
    pub model: Option<String>,
    /// `YearOfConstruction`.
    pub year_of_construction: Option<u16>,
    /// `Location`: where it stands (free text, e.g. `hall 2 / bay 4`).
    pub location: Option<String>,
}

impl Identification {
    /// The mandatory properties: (key, value), checked present and non-empty by `validate`.
    pub fn mandatory(&self) -> [(&'static str, Option<&str>); 3] {
        [
            ("manufacturer", self.manufacturer.as_deref()),
            ("serial_number", self.serial_number.as_deref()),
            ("product_instance_uri", self.product_instance_uri.as_deref()),
        ]
    }

    fn validate(&self) -> Result<(), (String, String)> {
        for (key, value) in self.mandatory() {
            if value.is_none_or(|v| v.trim().is_empty()) {
                return Err((
                    format!("opcua.identification.{key}"),
                    format!(
                        "expected the machine tool's {} (mandatory in OPC 40501-1 Identification)",
                        key.replace('_', " ")
                    ),
                ));
            }
        }
        let uri = self.product_instance_uri.as_deref().unwrap_or_default();
        if !uri.contains(':') || uri.contains(char::is_whitespace) {
            return Err((
                "opcua.identification.product_instance_uri".into(),
                format!("expected a URI (scheme:rest, no spaces), got {uri:?}"),
            ));
        }
        Ok(())
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpcUaUser {
    pub name: String,
    /// File holding the password (first line), relative to the field config; never in the config itself.
    pub password_file: PathBuf,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpcUaCertUser {
    pub name: String,
    /// The user's certificate (`.der` or `.pem`), relative to the field config; a session whose
    /// identity token carries any other certificate, or is not signed by its key, is refused.
    pub certificate: PathBuf,
}

fn default_listen() -> String {
    "127.0.0.1:4840".into()
}

impl OpcUaSection {
    pub fn anonymous(&self) -> bool {
        self.anonymous.unwrap_or(!self.has_users())
    }

    /// Any password or certificate user (they need the encrypted endpoint).
    pub fn has_users(&self) -> bool {
        !self.users.is_empty() || !self.cert_users.is_empty()
    }

    pub fn listen_addr(&self) -> SocketAddr {
        self.listen.parse().expect("validated at load")
    }

    /// Checks that need no file system: key path and what was expected on error.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let addr: SocketAddr = self.listen.parse().map_err(|_| {
            (
                "opcua.listen".to_string(),
                format!("expected ip:port, got {:?}", self.listen),
            )
        })?;
        self.listen_policy.check("opcua")?;
        if let Some(h) = &self.host
            && (h.is_empty() || h.contains(['/', ':', ' ']))
        {
            return Err((
                "opcua.host".into(),
                format!("expected a host name or IP without port or path, got {h:?}"),
            ));
        }
        if !self.anonymous() && !self.has_users() {
            return Err((
                "opcua.anonymous".into(),
                "anonymous = false without [opcua] users: nobody could connect".into(),
            ));
        }
        for (i, u) in self.users.iter().enumerate() {
            if u.name.trim().is_empty() || u.name.trim() != u.name {
                return Err((
                    format!("opcua.users[{i}].name"),
                    "expected a non-empty name without surrounding spaces".into(),
                ));
            }
            if self.users[..i].iter().any(|v| v.name == u.name) {
                return Err((
                    format!("opcua.users[{i}].name"),
                    format!("user {:?} configured twice", u.name),
                ));
            }
        }
        for (i, u) in self.cert_users.iter().enumerate() {
            let taken = self.users.iter().any(|v| v.name == u.name)
                || self.cert_users[..i].iter().any(|v| v.name == u.name);
            if u.name.trim().is_empty() || u.name.trim() != u.name || taken {
                return Err((
                    format!("opcua.cert_users[{i}].name"),
                    format!(
                        "expected a new non-empty name without surrounding spaces, got {:?}",
                        u.name
                    ),
                ));
            }
            let ext = u.certificate.extension().and_then(|e| e.to_str());
            if !matches!(ext, Some("der" | "pem")) {
                return Err((
                    format!("opcua.cert_users[{i}].certificate"),
                    format!(
                        "expected a .der or .pem file, got {}",
                        u.certificate.display()
                    ),
                ));
            }
        }
        if self.has_users() && self.pki_dir.is_none() {
            return Err((
                "opcua.pki_dir".into(),
                "required with users: passwords and user certificates only travel over the encrypted endpoint, which needs the server's certificate".into(),
            ));
        }
        match &self.identification {
            None => {
                return Err((
                    "opcua.identification".into(),
                    "expected an [opcua.identification] table with manufacturer, serial_number and product_instance_uri of the machine tool (mandatory in OPC 40501-1)".into(),
                ));
            }
            Some(id) => id.validate()?,
        }
        if addr.ip().is_unspecified() && self.host.is_none() {
            return Err((
                "opcua.host".into(),
                format!(
                    "listening on {addr}: expected `host`, the name clients use in the endpoint URL"
                ),
            ));
        }
        Ok(())
    }

    /// Resolve `pki_dir`, password and certificate files against the field config's folder, read
    /// each password (first line, at least 8 characters) and each user certificate. `retrocomp run`
    /// calls this at start.
    pub fn resolve(&mut self, base: &Path) -> Result<(), (String, String)> {
        if let Some(p) = &mut self.pki_dir {
            *p = base.join(&*p);
        }
        for (i, u) in self.users.iter_mut().enumerate() {
            u.password_file = base.join(&u.password_file);
            read_password(&u.password_file)
                .map_err(|what| (format!("opcua.users[{i}].password_file"), what))?;
        }
        #[cfg_attr(not(feature = "opcua"), allow(unused_variables))]
        for (i, u) in self.cert_users.iter_mut().enumerate() {
            u.certificate = base.join(&u.certificate);
            #[cfg(feature = "opcua")]
            opcua::crypto::CertificateStore::read_cert(&u.certificate).map_err(|e| {
                (
                    format!("opcua.cert_users[{i}].certificate"),
                    format!("expected an X.509 certificate: {e}"),
                )
            })?;
        }
        Ok(())
    }
}

/// The password in `path` (its first line), or what is wrong with the file.
pub fn read_password(path: &Path) -> Result<String, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let pw = text.lines().next().unwrap_or("").trim_end_matches('\r');
    if pw.chars().count() < 8 {
        return Err(format!(
            "{}: expected a password of at least 8 characters on its first line",
            path.display()
        ));
    }
    Ok(pw.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A valid identification, after `toml_text` (a table header ends the section's own keys).
    const IDENT: &str = "\n[identification]\nmanufacturer = \"Deckel\"\nserial_number = \"FP4-1234\"\n\
                         product_instance_uri = \"urn:example:deckel:FP4-1234\"\n";

    fn section(toml_text: &str) -> OpcUaSection {
        toml::from_str(&format!("{toml_text}{IDENT}")).unwrap()
    }

    #[test]
    fn identification_is_required_with_its_mandatory_properties() {
        let bare: OpcUaSection = toml::from_str("").unwrap();
        assert_eq!(bare.validate().unwrap_err().0, "opcua.identification");
        for (drop, key) in [
            ("manufacturer", "opcua.identification.manufacturer"),
            ("serial_number", "opcua.identification.serial_number"),
            (
                "product_instance_uri",
                "opcua.identification.product_instance_uri",
            ),
        ] {
            let text: String = IDENT
                .lines()
                .filter(|l| !l.starts_with(drop))
                .map(|l| format!("{l}\n"))
                .collect();
            let s: OpcUaSection = toml::from_str(&text).unwrap();
            let (k, what) = s.validate().unwrap_err();
            assert_eq!(k, key, "{what}");
        }
        let s: OpcUaSection =
            toml::from_str(&IDENT.replace("urn:example:deckel:FP4-1234", "not a uri")).unwrap();
        assert_eq!(
            s.validate().unwrap_err().0,
            "opcua.identification.product_instance_uri"
        );
    }

    #[test]
    fn defaults_are_loopback_and_anonymous() {
        let s = section("");
        assert_eq!(s.listen_addr().to_string(), "127.0.0.1:4840");
        assert!(s.anonymous());
        assert_eq!(s.validate(), Ok(()));
    }

    #[test]
    fn users_turn_anonymous_off_and_need_a_certificate_store() {
        let s = section(r#"users = [ { name = "mes", password_file = "mes.pw" } ]"#);
        assert!(!s.anonymous());
        let (key, what) = s.validate().unwrap_err();
        assert_eq!(key, "opcua.pki_dir", "{what}");
        let s = section(
            "pki_dir = \"pki\"\nanonymous = true\nusers = [ { name = \"mes\", password_file = \"mes.pw\" } ]",
        );
        assert!(s.anonymous());
        assert_eq!(s.validate(), Ok(()));
    }

    #[test]
    fn bad_values_name_their_key() {
        let cases = [
            ("listen = \"localhost\"", "opcua.listen"),
            ("listen = \"0.0.0.0:4840\"", "opcua.host"),
            ("host = \"box:4840\"", "opcua.host"),
            ("anonymous = false", "opcua.anonymous"),
            (
                "pki_dir = \"p\"\nusers = [ { name = \"a\", password_file = \"x\" }, { name = \"a\", password_file = \"y\" } ]",
                "opcua.users[1].name",
            ),
        ];
        for (text, want) in cases {
            let (key, what) = section(text).validate().unwrap_err();
            assert_eq!(key, want, "{text}: {what}");
        }
    }

    #[test]
    fn passwords_come_from_files_relative_to_the_config() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("mes.pw"), "correct-horse\nignored\n").unwrap();
        std::fs::write(dir.path().join("short.pw"), "abc\n").unwrap();
        let mut s = section(
            "pki_dir = \"pki\"\nusers = [ { name = \"mes\", password_file = \"mes.pw\" } ]",
        );
        s.resolve(dir.path()).unwrap();
        assert_eq!(s.pki_dir.as_deref(), Some(dir.path().join("pki").as_path()));
        assert_eq!(
            read_password(&s.users[0].password_file).unwrap(),
            "correct-horse"
        );
        for (file, want) in [("short.pw", "at least 8"), ("missing.pw", "cannot read")] {
            let mut s = section(&format!(
                "pki_dir = \"pki\"\nusers = [ {{ name = \"mes\", password_file = \"{file}\" }} ]"
            ));
            let (key, what) = s.resolve(dir.path()).unwrap_err();
            assert_eq!(key, "opcua.users[0].password_file");
            assert!(what.contains(want), "{what}");
        }
    }
}
