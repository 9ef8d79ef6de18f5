//! `/metrics` judged by Prometheus itself (Debian's `prometheus` package, installed by
//! `scripts/setup-peers.sh`): the real `retrocomp run` on the real hil-sim (`web_rig`), its
//! exposition checked by `promtool check metrics` (the project's naming rules: base units, `_total`
//! counters only), scraped by a real Prometheus started here on loopback, whose query API then
//! answers every expression of the shipped Grafana dashboard; the shipped alert rules pass
//! `promtool check rules` and their unit tests (`promtool test rules`).

use crate::web_rig;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A tool of Debian's `prometheus` package, or a failure saying how to install it.
fn tool(name: &str) -> PathBuf {
    let p = Path::new("/usr/bin").join(name);
    assert!(
        p.exists(),
        "{name} is missing: run scripts/setup-peers.sh (apt-get install prometheus)"
    );
    p
}

/// Runs `promtool ARGS` in `dir`; (success, stdout + stderr).
fn promtool(dir: &Path, args: &[&str], stdin: Option<&str>) -> (bool, String) {
    let mut child = Command::new(tool("promtool"))
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    if let Some(text) = stdin {
        use std::io::Write as _;
        child
            .stdin
            .take()
            .unwrap()
            .write_all(text.as_bytes())
            .unwrap();
    } else {
        drop(child.stdin.take());
    }
    let out = child.wait_with_output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

/// The metric family names of an exposition (from its `# TYPE` lines).
fn families(exposition: &str) -> BTreeSet<String> {
    exposition
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_string)
        .collect()
}

/// Every `retrocomp_…` name an expression uses, with histogram suffixes folded onto the family.
fn metric_names(expr: &str) -> Vec<String> {
    let mut out = vec![];
    let mut rest = expr;
    while let Some(i) = rest.find("retrocomp_") {
        let name: String = rest[i..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        rest = &rest[i + name.len()..];
        let family = ["_bucket", "_sum", "_count"]
            .iter()
            .find_map(|s| name.strip_suffix(s))
            .unwrap_or(&name)
            .to_string();
        out.push(family);
    }
    out
}

/// The shipped dashboard's query expressions.
fn dashboard_exprs() -> Vec<String> {
    let path = repo().join("deploy/grafana/retrocomp-dashboard.json");
    let dash: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let mut exprs = vec![];
    for p in dash["panels"].as_array().unwrap() {
        for t in p["targets"].as_array().unwrap() {
            exprs.push(t["expr"].as_str().unwrap().to_string());
        }
    }
    assert!(exprs.len() >= 10, "the dashboard has its panels");
    exprs
}

struct Prometheus {
    child: Child,
    addr: String,
}

impl Drop for Prometheus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A real Prometheus on loopback scraping `target` every second, its data in `dir`.
fn start_prometheus(dir: &Path, target: &str) -> Prometheus {
    let cfg = dir.join("prometheus.yml");
    std::fs::write(
        &cfg,
        format!(
            "global:\n  scrape_interval: 1s\n  evaluation_interval: 1s\nscrape_configs:\n  - job_name: retrocomp\n    static_configs:\n      - targets: [\"{target}\"]\n"
        ),
    )
    .unwrap();
    let addr = format!("127.0.0.1:{}", free_port());
    let log = std::fs::File::create(dir.join("prometheus.log")).unwrap();
    let child = Command::new(tool("prometheus"))
        .arg(format!("--config.file={}", cfg.display()))
        .arg(format!(
            "--storage.tsdb.path={}",
            dir.join("tsdb").display()
        ))
        .arg(format!("--web.listen-address={addr}"))
        .stdout(log.try_clone().unwrap())
        .stderr(log)
        .spawn()
        .unwrap();
    Prometheus { child, addr }
}

fn url_encode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                char::from(b).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// One instant query against Prometheus' HTTP API; the parsed answer, or None if it did not answer.
fn query(rig: &web_rig::Rig, prom: &Prometheus, expr: &str) -> Option<Value> {
    use retrocomp_gateway::northbound::http::request;
    let path = format!("/api/v1/query?query={}", url_encode(expr));
    let (code, body) = rig
        .rt
        .block_on(request(
            &prom.addr,
            "GET".parse().unwrap(),
            &path,
            &[],
            Default::default(),
            Duration::from_secs(10),
        ))
        .ok()?;
    let v: Value = serde_json::from_str(&body).ok()?;
    (code == 200 || code == 400 || code == 422).then_some(v)
}

#[test]
fn prometheus_accepts_scrapes_and_answers_the_dashboard_of_a_running_gateway() {
    let _turn = crate::turn::take(file!());
    let mut rig = web_rig::start("gateway_prometheus", 8, "");
    rig.wait_status("tracking", Duration::from_secs(60), |s| {
        s["axes"]
            .as_array()
            .is_some_and(|a| a.iter().all(|a| a["mode"] == "tracking"))
    });
    let (code, metrics) = rig.call("GET", "/metrics", None, "");
    assert_eq!(code, 200, "{metrics}");

    // promtool's own lint: no unit, suffix or type complaint, nothing printed.
    let (ok, lint) = promtool(&rig.dir, &["check", "metrics"], Some(&metrics));
    assert!(
        ok && lint.trim().is_empty(),
        "promtool check metrics:\n{lint}\n---\n{metrics}"
    );
    let fams = families(&metrics);
    for must in [
        "retrocomp_build_info",
        "retrocomp_cycle_duration_seconds",
        "retrocomp_cycles_late_total",
        "retrocomp_correction_applied_meters",
        "retrocomp_channel_temperature_celsius",
    ] {
        assert!(
            fams.contains(must),
            "{must} missing from /metrics:\n{metrics}"
        );
    }
    assert!(
        !fams.iter().any(|f| f.ends_with("_um")),
        "a family in µm: {fams:?}"
    );

    // Every metric the dashboard and the alert rules use is one the box exposes.
    let rules =
        std::fs::read_to_string(repo().join("deploy/prometheus/retrocomp-alerts.yml")).unwrap();
    let exprs = dashboard_exprs();
    for name in exprs
        .iter()
        .flat_map(|e| metric_names(e))
        .chain(metric_names(&rules))
    {
        assert!(fams.contains(&name), "{name} is used but not exposed");
    }

    // A real Prometheus scrapes the box, and answers every dashboard expression.
    let prom = start_prometheus(&rig.dir, &rig.addr);
    let deadline = Instant::now() + Duration::from_secs(60);
    let applied = loop {
        rig.assert_alive("while Prometheus scrapes");
        let v = query(&rig, &prom, "retrocomp_correction_applied_meters")
            .filter(|v| v["status"] == "success")
            .map(|v| v["data"]["result"].as_array().cloned().unwrap_or_default())
            .unwrap_or_default();
        if v.len() == 3 {
            break v;
        }
        assert!(
            Instant::now() < deadline,
            "Prometheus did not scrape the box within 60 s: {}",
            std::fs::read_to_string(rig.dir.join("prometheus.log")).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    let values: Vec<f64> = applied
        .iter()
        .map(|s| s["value"][1].as_str().unwrap().parse().unwrap())
        .collect();
    // The rig's clamp is 200 µm (src/demo/field.rs): in metres every value is within 2e-4, and
    // the warm mill needs some correction (≥ 0.5 µm on one axis); in µm they would be ≥ 0.5.
    assert!(
        values.iter().all(|v| v.abs() <= 200e-6) && values.iter().any(|v| v.abs() >= 0.5e-6),
        "applied correction in metres: {applied:?}"
    );
    let up = query(&rig, &prom, "up{job=\"retrocomp\"}").unwrap();
    assert_eq!(up["data"]["result"][0]["value"][1], "1", "{up}");
    for e in &exprs {
        let e = e
            .replace("$__rate_interval", "10s")
            .replace("$instance", ".*");
        let v = query(&rig, &prom, &e).unwrap();
        assert_eq!(v["status"], "success", "dashboard expression `{e}`: {v}");
    }
}

#[test]
fn the_shipped_alert_rules_pass_promtool_and_their_unit_tests() {
    let _turn = crate::turn::take(file!());
    let dir = repo().join("deploy/prometheus");
    let (ok, out) = promtool(&dir, &["check", "rules", "retrocomp-alerts.yml"], None);
    assert!(ok && out.contains("SUCCESS: 5 rules found"), "{out}");
    let (ok, out) = promtool(&dir, &["test", "rules", "retrocomp-alerts.test.yml"], None);
    assert!(ok && out.contains("SUCCESS"), "{out}");
    let (ok, out) = promtool(&dir, &["check", "config", "prometheus.yml"], None);
    assert!(ok, "{out}");
}
