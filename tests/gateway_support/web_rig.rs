//! The rig of the live-page tests (`gateway_web_actions`, `gateway_web_browser`): the real
//! `hil-sim serve` (the demo mill, real time, CAN through a loopback socketcand hub, the PLC on
//! Modbus TCP, weighing lines on a pty) and the real `retrocomp run` child with an API token, its
//! status address read from its log. Dropping the rig kills both.

use std::path::{Path, PathBuf};
use std::process::Child;
use std::time::{Duration, Instant};

use super::configs::{field_toml, sim_io_toml, sim_machine_toml};
use super::run;

pub(crate) const TOKEN: &str = "shopfloor-test-token-0123";

pub(crate) struct Rig {
    pub dir: PathBuf,
    pub sim: run::Sim,
    pub gw: Child,
    pub log: PathBuf,
    pub addr: String,
    pub rt: tokio::runtime::Runtime,
    _hub: retrocomp_bus::can::Hub,
    pub t0: Instant,
}

/// Starts hil-sim running `strokes` strokes (3 s each after 1 s of dwell) with the extra
/// `[[io.faults]]` TOML `io_faults`, and the gateway on it; waits for its status address.
pub(crate) fn start(name: &str, strokes: usize, io_faults: &str) -> Rig {
    start_with(name, strokes, io_faults, "")
}

/// [`start`] with `field_extra` appended to the gateway's field config (e.g. `[gateway.models]`
/// with absolute paths: the run folder is made anew by `start`).
pub(crate) fn start_with(name: &str, strokes: usize, io_faults: &str, field_extra: &str) -> Rig {
    let hil_sim = super::hil_sim::hil_sim_next_to_retrocomp();
    let dir = run::run_dir(name);
    let (rt, hub) = run::loopback_hub();
    let truth = run::demo_truth_model();
    let port = hub.local_addr().port();
    let sim_cfg = dir.join("sim.toml");
    let sim_text = sim_machine_toml(strokes, &truth)
        + "\n"
        + &sim_io_toml(port, &dir.join("weighing-pty"), None)
        + io_faults;
    std::fs::write(&sim_cfg, sim_text).unwrap();
    let sim = run::Sim::spawn(&hil_sim, &sim_cfg, &dir.join("out"));
    let [plc, pty] = <[String; 2]>::try_from(
        sim.wait_for(&["hil-sim: modbus tcp on ", "hil-sim: weighing lines on "]),
    )
    .unwrap();
    let t0 = Instant::now();
    let field = dir.join("field.toml");
    let text = field_toml(port, &plc, Path::new(&pty)).replacen(
        "status_listen = \"127.0.0.1:0\"",
        &format!("status_listen = \"127.0.0.1:0\"\napi_token = \"{TOKEN}\""),
        1,
    );
    assert!(text.contains("api_token"), "field config has the token");
    let text = text + field_extra;
    std::fs::write(&field, text).unwrap();
    let (gw, log) = run::start_gateway(&dir, "gateway.log", &field, &truth);
    let mut rig = Rig {
        dir,
        sim,
        gw,
        log,
        addr: String::new(),
        rt,
        _hub: hub,
        t0,
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while rig.addr.is_empty() {
        rig.assert_alive("at start");
        assert!(
            Instant::now() < deadline,
            "no status address in the gateway log:\n{}",
            rig.log_text()
        );
        if let Some(a) = log_value(&rig.log, "bound") {
            rig.addr = a;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    rig
}

fn log_value(log: &Path, key: &str) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    let line = text.lines().find(|l| l.contains(&format!(" {key}=")))?;
    let i = line.find(&format!(" {key}="))? + key.len() + 2;
    Some(line[i..].split_whitespace().next()?.to_string())
}

impl Rig {
    pub(crate) fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    pub(crate) fn assert_alive(&mut self, when: &str) {
        if let Some(st) = self.gw.try_wait().unwrap() {
            panic!("the gateway died {when} ({st}):\n{}", self.log_text());
        }
    }

    /// Waits for hil-sim to end the program by itself (then its log of every PLC write is
    /// complete) and returns that log, `out/plc_writes.csv`.
    pub(crate) fn plc_writes_after_sim_ends(&mut self) -> String {
        let deadline = Instant::now() + Duration::from_secs(60);
        while self.sim.child.try_wait().unwrap().is_none() {
            self.assert_alive("while hil-sim finishes");
            assert!(
                Instant::now() < deadline,
                "hil-sim did not finish:\n{}",
                self.sim.log_text()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        std::fs::read_to_string(self.dir.join("out/plc_writes.csv")).unwrap()
    }

    /// One request; (status code, body).
    pub(crate) fn call(
        &self,
        method: &str,
        path: &str,
        auth: Option<&str>,
        body: &str,
    ) -> (u16, String) {
        use retrocomp_gateway::northbound::http::request;
        let bearer = auth.map(|t| format!("Bearer {t}"));
        let mut h = vec![("content-type", "application/json")];
        if let Some(b) = &bearer {
            h.push(("authorization", b.as_str()));
        }
        let m = method.parse().unwrap();
        let body = body.to_string().into();
        self.rt
            .block_on(request(
                &self.addr,
                m,
                path,
                &h,
                body,
                Duration::from_secs(5),
            ))
            .unwrap_or_else(|e| panic!("{method} {path}: {e}"))
    }

    /// `/status` as JSON (None before the first cycle or when the answer is not 200).
    pub(crate) fn status(&self) -> Option<serde_json::Value> {
        let (code, body) = self.call("GET", "/status", None, "");
        (code == 200).then(|| serde_json::from_str(&body).unwrap())
    }

    /// Polls `/status` every 20 ms until `pred` holds (a generous `within`, not a measurement).
    pub(crate) fn wait_status(
        &mut self,
        what: &str,
        within: Duration,
        pred: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let deadline = Instant::now() + within;
        loop {
            self.assert_alive(what);
            if let Some(s) = self.status()
                && pred(&s)
            {
                return s;
            }
            assert!(
                Instant::now() < deadline,
                "{what}: not seen within {within:?}; last /status: {:?}",
                self.status()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        let _ = self.gw.kill();
        let _ = self.gw.wait();
        let _ = self.sim.child.kill();
        let _ = self.sim.child.wait();
    }
}

/// Applied correction of every axis, µm, from a `/status` body.
pub(crate) fn applied(s: &serde_json::Value) -> Vec<(String, f64)> {
    s["axes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| {
            (
                a["axis"].as_str().unwrap().to_string(),
                a["applied_um"].as_f64().unwrap(),
            )
        })
        .collect()
}
