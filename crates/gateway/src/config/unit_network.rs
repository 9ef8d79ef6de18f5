//! The network a field file needs under the shipped systemd unit: `deploy/retrocomp.service` denies
//! every IP peer but localhost (`IPAddressDeny=any`, `IPAddressAllow=localhost`), so each remote
//! peer the field file names (a Modbus source's host, the origin-shift controller, a socketcand
//! daemon, the MQTT broker) must be allowed in a drop-in (`/etc/systemd/system/retrocomp.service.d/
//! network.conf`, shipped as `deploy/retrocomp.service.d/network.conf`). `retrocomp check-config
//! --field FILE` prints that drop-in from [`UnitNetwork::of`].
//!
//! systemd's `IPAddressAllow=` filters on the remote address of packets in both directions, so a
//! listener open beyond loopback (origin-shift server, OPC UA, the status endpoint) also needs its
//! peers' addresses: those cannot be read from the field file, and a note says so. Host names are
//! not allowed by systemd either (addresses and prefixes only): a note names them.

use std::collections::BTreeSet;
use std::fmt::Write;
use std::net::{IpAddr, SocketAddr};

use crate::config::FieldConfig;
use crate::sinks::origin_shift::client::Transport;
use crate::sinks::origin_shift::server::ServerTransport;
use retrocomp_bus::can::CanBackendConfig;
use retrocomp_bus::modbus::TransportKind;

/// The remote peers of one field file, as the unit's IP filter sees them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct UnitNetwork {
    /// Addresses to allow (loopback ones are left out: the unit allows localhost already).
    pub allow: BTreeSet<IpAddr>,
    /// What cannot be turned into an address here (host names, listeners' unknown peers).
    pub notes: Vec<String>,
}

impl UnitNetwork {
    /// Every peer `cfg` connects to, and every listener it opens beyond loopback.
    pub fn of(cfg: &FieldConfig) -> Self {
        let mut n = UnitNetwork::default();
        if let Some(CanBackendConfig::Socketcand { host, .. }) = &cfg.can {
            n.peer("[can] host", host);
        }
        for m in cfg.modbus.iter().flat_map(|m| &m.source) {
            if m.transport == TransportKind::Tcp {
                let host = m.host.as_deref().unwrap_or("");
                n.peer(&format!("[[modbus.source]] {:?} host", m.name), host);
            }
        }
        if let Some(os) = &cfg.sink.origin_shift
            && let Transport::Tcp { address } = &os.transport
        {
            n.peer_with_port("[sink.origin_shift] transport.address", address);
        }
        if let Some(mqtt) = cfg.telemetry.as_ref().and_then(|t| t.mqtt.as_ref()) {
            match mqtt.host_port() {
                Ok((host, _)) => n.peer("[telemetry.mqtt] broker", &host),
                Err(e) => n.notes.push(format!("[telemetry.mqtt] broker: {e}")),
            }
        }
        if let Some(srv) = &cfg.sink.origin_shift_server
            && let ServerTransport::Tcp { listen } = &srv.transport
        {
            n.listener(
                "[sink.origin_shift_server] transport.listen",
                listen,
                "the controller",
            );
        }
        if let Some(o) = &cfg.opcua {
            n.listener("[opcua] listen", &o.listen, "the OPC UA clients");
        }
        n.listener(
            "[gateway] status_listen",
            &cfg.gateway.status_listen,
            "the browsers and scrapers of the status endpoint",
        );
        n
    }

    /// A peer given as a bare host (a name or an address).
    fn peer(&mut self, key: &str, host: &str) {
        match host.trim_matches(['[', ']']).parse::<IpAddr>() {
            Ok(ip) if ip.is_loopback() => {}
            Ok(ip) => {
                self.allow.insert(ip);
            }
            Err(_) => self.notes.push(format!(
                "{key} = {host:?} is a host name: systemd allows addresses only, add the address it resolves to"
            )),
        }
    }

    /// A peer given as `host:port`.
    fn peer_with_port(&mut self, key: &str, address: &str) {
        match address.parse::<SocketAddr>() {
            Ok(sa) => self.peer(key, &sa.ip().to_string()),
            Err(_) => {
                let host = address.rsplit_once(':').map_or(address, |(h, _)| h);
                self.peer(key, host);
            }
        }
    }

    /// A listener: loopback needs nothing; anything else needs its peers, which the file does not name.
    fn listener(&mut self, key: &str, listen: &str, who: &str) {
        let loopback = listen
            .parse::<SocketAddr>()
            .is_ok_and(|sa| sa.ip().is_loopback());
        if !loopback {
            self.notes.push(format!(
                "{key} = {listen:?} accepts connections beyond loopback: add the addresses of {who}"
            ));
        }
    }

    /// The drop-in to install as `/etc/systemd/system/retrocomp.service.d/network.conf`.
    pub fn drop_in(&self) -> String {
        let mut o = String::from(
            "# /etc/systemd/system/retrocomp.service.d/network.conf\n\
             # then: systemctl daemon-reload && systemctl restart retrocomp\n",
        );
        for note in &self.notes {
            let _ = writeln!(o, "# {note}");
        }
        o.push_str("[Service]\n");
        if self.allow.is_empty() {
            o.push_str("# no remote peer: the unit's IPAddressAllow=localhost is enough\n");
        } else {
            let list: Vec<String> = self.allow.iter().map(IpAddr::to_string).collect();
            let _ = writeln!(o, "IPAddressAllow={}", list.join(" "));
        }
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped(name: &str) -> UnitNetwork {
        let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join(name);
        UnitNetwork::of(&FieldConfig::load(&path).unwrap())
    }

    #[test]
    fn the_shipped_field_files_peers_are_allowed_and_loopback_is_not_repeated() {
        let n = shipped("deploy/field/sensors-can-modbus-serial.toml");
        let d = n.drop_in();
        // The Modbus source's host and the controller (origin-shift sink), each once, in order.
        assert!(
            d.contains("\nIPAddressAllow=192.168.10.20 192.168.10.30\n"),
            "{d}"
        );
        assert!(n.notes.is_empty(), "{n:?}");

        let n = shipped("deploy/walkthrough/field.toml");
        assert!(n.allow.is_empty(), "{n:?}");
        assert!(n.drop_in().contains("no remote peer"), "{}", n.drop_in());
    }

    #[test]
    fn host_names_and_open_listeners_are_notes_not_addresses() {
        let mut n = UnitNetwork::default();
        n.peer("[can] host", "canbox.local");
        n.peer_with_port("[sink.origin_shift] transport.address", "plc:502");
        n.peer_with_port("[sink.origin_shift] transport.address", "[fd00::7]:502");
        n.listener("[opcua] listen", "0.0.0.0:4840", "the OPC UA clients");
        n.listener("[gateway] status_listen", "127.0.0.1:9184", "browsers");
        assert_eq!(
            n.allow.iter().map(IpAddr::to_string).collect::<Vec<_>>(),
            ["fd00::7"]
        );
        assert_eq!(n.notes.len(), 3, "{:?}", n.notes);
        assert!(
            n.notes[0].contains("\"canbox.local\" is a host name"),
            "{:?}",
            n.notes
        );
        assert!(n.notes[1].contains("\"plc\""), "{:?}", n.notes);
        assert!(n.notes[2].contains("0.0.0.0:4840"), "{:?}", n.notes);
    }
}
