//! The 30-minute warm-up of `dnc_peers`' comparison: one machine (hil-sim), one program, compensated
//! three ways. The hidden machine: X scale error 20 ppm (8 µm at X400) and a spindle housing that
//! warms with τ 600 s towards 12 K above ambient at 8000 rpm, growing the tool point along X by
//! 3 µm/K; its PT100 (`T_spindle_C`, first-order lag 5 s, Modbus input register 0, 0.1 °C) is what
//! the box reads. The box's model knows both (EXX table 0 → 8 µm over 0…400 mm, 3 µm/K on the
//! spindle sensor). Part error at a dwell end = true tool tip − the program's nominal end point, µm:
//! `(set-point − nominal)·1000 + hil-sim's true error there` (`dwell_ends.csv`).

use super::{dnc, hil_sim, pair, peers, s};

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Simulated seconds per wall second of the paced runs.
pub(crate) const SPEED: f64 = 20.0;
/// Out-and-back strokes X50 ↔ X350 (6 s at F3000) each followed by a 2 s dwell: 30 min.
pub(crate) const STROKES: usize = 225;

/// `dnc_peers`' model with the warm-up machine's numbers: EXX the same both ways, 3 µm/K.
pub(crate) fn model() -> String {
    let m = super::MODEL
        .replace("reverse_um = [-3.0, 5.0]", "reverse_um = [0.0, 8.0]")
        .replace("b_um_per_K = [2.0]", "b_um_per_K = [3.0]");
    assert!(
        m.contains("reverse_um = [0.0, 8.0]") && m.contains("[3.0]"),
        "dnc_peers' MODEL changed"
    );
    m
}

/// The program's nominal end point of stroke `i` (where its dwell is).
pub(crate) fn nominal_mm(i: usize) -> [f64; 3] {
    let x = if i.is_multiple_of(2) { 350.0 } else { 50.0 };
    [x, (i % 20) as f64, 0.0]
}

pub(crate) fn program() -> String {
    let mut s = String::from("%\n(WARM-UP)\nG21 G90 G17 G94\nG0 X50 Y0 Z0\nS8000 M3\nG1 F3000\n");
    for i in 0..STROKES {
        let [x, y, _] = nominal_mm(i);
        s.push_str(&format!("X{x:.0} Y{y:.0}\nG4 P2\n"));
    }
    s.push_str("M5\nM30\n%\n");
    s
}

/// hil-sim's machine; `tail` adds the program source. Paced runs keep their pace under
/// `SCHED_FIFO` when allowed (a starved simulator reads the DNC line late and overruns its buffer).
pub(crate) fn sim_toml(paced: bool, tail: &str) -> String {
    sim_toml_every(paced, tail, 1.0)
}

/// [`sim_toml`] sampling (recording, Modbus input registers) every `every_s`.
pub(crate) fn sim_toml_every(paced: bool, tail: &str, every_s: f64) -> String {
    format!(
        r#"seed = 7
[clock]
realtime = {paced}
speed = {SPEED}
max_duration_s = 2400.0
realtime_priority = 20

[program]
start_mm = [50.0, 0.0, 0.0]
{tail}
[servo]
ideal = true
count_um = 0.1

[truth.builtin]
exx_ppm = 20.0

[hidden.thermal]
ambient_C = 20.0

[[hidden.thermal.nodes]]
name = "spindle"
tau_s = 600.0
rise_C_per_krpm = 1.5

[[hidden.thermal.sensors]]
name = "spindle"
node = "spindle"
tau_s = 5.0

[[hidden.thermal.effects]]
kind = "growth"
node = "spindle"
axis = "x"
um_per_K = 3.0

[plc]
scan_s = 0.004
word = "int32"
word_order = "high_first"
lsb_um = 0.5
first_register = 0
handshake = {{ strobe_register = 10, ack_register = 11 }}

[record]
every_s = {every_s}
"#
    )
}

/// The DNC run's hil-sim: the program arrives on `dnc_dev`; the PT100 on Modbus TCP `mb_port`.
pub(crate) fn sim_dnc_toml(dnc_dev: &Path, mb_port: u16) -> String {
    sim_toml(true, "")
        + &format!(
            r#"
[io.modbus]
tcp_bind = "127.0.0.1:{mb_port}"
temps_first_input = 0

[io.dnc]
device = "{}"
baud = 19200
buffer_lines = 5
"#,
            dnc_dev.display()
        )
}

/// The origin-shift run's hil-sim: the program as a file; the PT100 (input register 0) and the
/// axis positions (input registers 10.., int32, 1 µm) sampled every 50 ms of simulated time on
/// Modbus TCP `mb_port`, where the PLC window (int32 shifts at 0, 2, 4, 0.5 µm, strobe 10, ack 11)
/// is served too.
pub(crate) fn sim_shift_toml(program: &Path, mb_port: u16) -> String {
    let tail = format!("gcode_path = \"{}\"", program.display());
    sim_toml_every(true, &tail, 0.05)
        + &format!(
            r#"
[io.modbus]
tcp_bind = "127.0.0.1:{mb_port}"
temps_first_input = 0
positions_first_input = 10
position_lsb_um = 1.0
"#
        )
}

/// A field file in `dir` with the model next to it: `[gateway]`/`[safety]`/`[direction]` keys from
/// `limits` (cycle 5 ms, clamp 100 µm), axis X, one Modbus TCP source on `mb_port` polled every
/// `period_s` with `channels`, then `tail`.
fn write_field(dir: &Path, limits: [f64; 5], mb_port: u16, channels: &str, tail: &str) -> PathBuf {
    std::fs::write(dir.join("model.toml"), model()).unwrap();
    let [
        thermal_period_s,
        cap_um,
        ramp_um_per_s,
        switch_time_s,
        period_s,
    ] = limits;
    let status_port = peers::free_port();
    let text = format!(
        r#"[gateway]
name = "warmup"
cycle_ms = 5
thermal_period_s = {thermal_period_s}
realtime_priority = 20
status_listen = "127.0.0.1:{status_port}"
[safety]
max_correction_um = 100.0
max_change_um_per_cycle = {cap_um}
ramp_um_per_s = {ramp_um_per_s}
stale_hold_s = 2.0
[direction]
deadband_mm = 0.005
switch_time_s = {switch_time_s}
[model]
path = "model.toml"
[[axis]]
name = "x"
position_channel = "x_mm"
[[modbus.source]]
name = "hil-sim"
transport = "tcp"
host = "127.0.0.1"
port = {mb_port}
period_s = {period_s}
timeout_s = 0.5
backoff_min_s = 0.1
backoff_max_s = 0.5
channel = [
  {{ channel = "T_spindle_C", kind = "input", address = 0, type = "int16", scale = 0.1 }},
  {channels}
]
{tail}"#
    );
    let p = dir.join("field.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// `retrocomp run`'s field file for the origin-shift run: limits a 2 s dwell (100 ms of wall time
/// at 20×) settles in; the PT100 and the X position polled every 20 ms; hil-sim's PLC window.
pub(crate) fn run_field_toml(dir: &Path, mb_port: u16) -> PathBuf {
    let tail = format!(
        r#"[sink.origin_shift]
transport = {{ kind = "tcp", address = "127.0.0.1:{mb_port}" }}
request_timeout_ms = 300
reconnect_min_ms = 20
reconnect_max_ms = 200
write_period_ms = 10

[sink.origin_shift.map]
[[sink.origin_shift.map.axis]]
axis = "x"
address = 0
kind = "int32"
lsb_um = 0.5
sign = 1

[sink.origin_shift.map.handshake]
strobe_address = 10
ack_address = 11
timeout_ms = 200
"#
    );
    let x = r#"{ channel = "x_mm", kind = "input", address = 10, type = "int32", scale = 0.001 },"#;
    write_field(dir, [0.05, 2.0, 200.0, 0.02, 0.02], mb_port, x, &tail)
}

/// `retrocomp dnc`'s field file (and the model next to it): the spindle PT100 read from hil-sim
/// every 50 ms; each block held until the one before it is estimated to run (`lead_blocks = 1`,
/// the control paced at `SPEED` = 20), and its correction predicted for when it ends from the
/// slope over the last 2 s of the box's clock (40 s simulated, ≪ the growth's τ 600 s; at most
/// 2 s = 40 s ahead). `x_mm` is read from the same register only because the field file must have a source for every axis' position channel: `retrocomp dnc` takes the
/// position of each block from the block itself and never uses that value.
pub(crate) fn field_toml(dir: &Path, mb_port: u16) -> PathBuf {
    let x = r#"{ channel = "x_mm", kind = "input", address = 0, type = "int16", scale = 0.1 },"#;
    let tail = "[dnc]\nbaud = 19200\nparity = \"none\"\ndata_bits = 8\nstop_bits = 1\n\
                flow = \"xon_xoff\"\nmax_line_chars = 40\nmax_change_um_per_block = 10.0\n\
                lead_blocks = 1\ncontrol_speed = 20.0\npredict_drift = true\n\
                drift_window_s = 2.0\npredict_max_s = 2.0\n";
    write_field(dir, [0.05, 0.5, 20.0, 0.1, 0.05], mb_port, x, tail)
}

/// Part errors (3-D length, µm) at the dwell ends of `dwell_ends.csv`, in program order.
pub(crate) fn part_errors_um(dwell_ends: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(dwell_ends)
        .unwrap_or_else(|e| panic!("{}: {e}", dwell_ends.display()));
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("t_s,line,x_mm,y_mm,z_mm,ex_um,ey_um,ez_um")
    );
    lines
        .enumerate()
        .map(|(i, l)| {
            let f: Vec<f64> = l.split(',').map(|v| v.parse().unwrap()).collect();
            let nom = nominal_mm(i);
            let e: Vec<f64> = (0..3)
                .map(|k| (f[2 + k] - nom[k]) * 1000.0 + f[5 + k])
                .collect();
            // The set-point is the nominal within what a correction can be (≤ 100 µm).
            for k in 0..3 {
                assert!(
                    (f[2 + k] - nom[k]).abs() < 0.1,
                    "dwell {i} at {:?}, nominal {nom:?}",
                    &f[2..5]
                );
            }
            e.iter().map(|v| v * v).sum::<f64>().sqrt()
        })
        .collect()
}

/// (RMS, max) of part errors, µm.
pub(crate) fn summary(e: &[f64]) -> (f64, f64) {
    let rms = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
    (rms, e.iter().cloned().fold(0.0, f64::max))
}

/// Wait for a child to exit (a hang guard, never a timing assertion); its status and stderr.
pub(crate) fn wait_exit(mut c: std::process::Child, what: &str, limit_s: u64) -> (bool, String) {
    let deadline = Instant::now() + Duration::from_secs(limit_s);
    let st = loop {
        if let Some(st) = c.try_wait().unwrap() {
            break st;
        }
        assert!(Instant::now() < deadline, "{what} did not finish");
        std::thread::sleep(Duration::from_millis(200));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(c.stderr.as_mut().unwrap(), &mut err).unwrap();
    (st.success(), err)
}

/// Run `cmd` to its end; its stderr is the failure message when it does not succeed.
fn run_ok(cmd: &mut Command) {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

pub(crate) fn wait_listening(port: u16) {
    let deadline = Instant::now() + Duration::from_secs(30);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            Instant::now() < deadline,
            "hil-sim's Modbus server did not come up"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A run whose simulated control fell this far behind the wall clock (hil-sim's "behind real
/// time" episodes, SCHED_FIFO notwithstanding) judges the host, not the box: the box paces the
/// transfer by the control's estimated execution in wall time, and a control that stood still
/// for 0.25 s of wall time (5 s simulated at 20×) then reads every byte that arrived meanwhile
/// at one instant, past its XOFF. A real control does not stand still.
const VOID_LAG_MS: f64 = 250.0;

/// How many times a void run is repeated before the test fails for want of a usable host.
const ATTEMPTS: usize = 3;

/// The largest lag hil-sim reported (ms), or infinity for an episode still open at its end.
fn worst_lag_ms(sim_err: &str) -> f64 {
    let lines: Vec<&str> = sim_err
        .lines()
        .filter(|l| l.starts_with("hil-sim: behind real time"))
        .collect();
    let started = lines.iter().filter(|l| l.contains(" started ")).count();
    let cleared = lines.iter().filter(|l| l.contains(" cleared ")).count();
    if started > cleared {
        return f64::INFINITY;
    }
    // "… (lag 60.0 ms)" at a start, "… max lag so far 120.5 ms)" at a clear.
    lines
        .iter()
        .filter_map(|l| {
            let after = l.rsplit("lag ").next()?.trim_start_matches("so far ");
            after.split(' ').next()?.parse::<f64>().ok()
        })
        .fold(0.0, f64::max)
}

/// The test of `dnc_peers` (its doc comment says what it runs and asserts). A run is repeated
/// when a simulator fell behind real time (`VOID_LAG_MS`); every repeat is said.
pub(crate) fn three_ways() {
    for attempt in 1..=ATTEMPTS {
        match three_ways_once() {
            Ok(()) => return,
            Err(why) => eprintln!("attempt {attempt} of {ATTEMPTS} void: {why}"),
        }
    }
    panic!(
        "all {ATTEMPTS} runs void: the simulated controls fell behind real time by more than \
         {VOID_LAG_MS} ms each time, so this host cannot stand in for a controller now"
    );
}

fn three_ways_once() -> Result<(), String> {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let hil = hil_sim::hil_sim_next_to_retrocomp();
    let prog = dir.join("program.ngc");
    std::fs::write(&prog, program()).unwrap();
    let sub = |name: &str| {
        let d = dir.join(name);
        std::fs::create_dir_all(&d).unwrap();
        d
    };
    let serve = |cfg: &Path, out: &Path| {
        Command::new(&hil)
            .args(["serve", "--config", s(cfg), "--out", s(out)])
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };

    // (a) origin shift.
    let (a_dir, a_port) = (sub("shift"), peers::free_port());
    let a_sim_cfg = a_dir.join("sim.toml");
    std::fs::write(&a_sim_cfg, sim_shift_toml(&prog, a_port)).unwrap();
    let a_sim = serve(&a_sim_cfg, &a_dir.join("out"));
    // (b) live DNC.
    let (_socat, ctl_dev, box_dev) = pair(dir, "dnc");
    let (b_dir, b_port) = (sub("dnc_run"), peers::free_port());
    let b_sim_cfg = b_dir.join("sim.toml");
    std::fs::write(&b_sim_cfg, sim_dnc_toml(&ctl_dev, b_port)).unwrap();
    let b_sim = serve(&b_sim_cfg, &b_dir.join("out"));
    wait_listening(a_port);
    wait_listening(b_port);
    let a_field = run_field_toml(&sub("run_box"), a_port);
    let a_box = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["run", "--config", s(&a_field)])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let b_field = field_toml(&sub("dnc_box"), b_port);
    let b_box = dnc(&b_field, &box_dev, &dir.join("sent.csv"))
        .args(["--program", s(&prog)])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();

    // (c) the frozen model, while the paced runs go on.
    let c_dir = sub("frozen");
    let frozen = c_dir.join("frozen.ngc");
    field_toml(&c_dir, 1);
    run_ok(
        Command::new(env!("CARGO_BIN_EXE_retrocomp"))
            .args(["nc", s(&prog), "--model", s(&c_dir.join("model.toml"))])
            .args(["--out", s(&frozen)]),
    );
    let c_sim_cfg = c_dir.join("sim.toml");
    let tail = format!("gcode_path = \"{}\"", frozen.display());
    std::fs::write(&c_sim_cfg, sim_toml(false, &tail)).unwrap();
    run_ok(Command::new(&hil).args([
        "run",
        "--config",
        s(&c_sim_cfg),
        "--out",
        s(&c_dir.join("out")),
    ]));

    // A hang guard only: 30 min / 20 ≈ 90 s of wall time when hil-sim keeps pace.
    let (ok, b_err) = wait_exit(b_sim, "hil-sim (DNC)", 900);
    assert!(ok, "hil-sim serve (DNC) failed:\n{b_err}");
    let (ok, a_err) = wait_exit(a_sim, "hil-sim (origin shift)", 900);
    assert!(ok, "hil-sim serve (origin shift) failed:\n{a_err}");
    let (ok, box_err) = wait_exit(b_box, "retrocomp dnc", 60);
    assert!(ok, "retrocomp dnc failed:\n{box_err}");
    // SIGTERM to the `retrocomp run` this test started: its machine has finished.
    Command::new("kill")
        .args(["-TERM", &a_box.id().to_string()])
        .status()
        .unwrap();
    let (_, run_err) = wait_exit(a_box, "retrocomp run", 60);
    let mut lags = Vec::new();
    for (what, err) in [("DNC", &b_err), ("origin shift", &a_err)] {
        let lag_ms = worst_lag_ms(err);
        lags.push((what, lag_ms));
        if lag_ms >= VOID_LAG_MS {
            let said: Vec<&str> = err
                .lines()
                .filter(|l| l.contains("behind real time"))
                .collect();
            return Err(format!(
                "hil-sim ({what}) fell {lag_ms:.0} ms behind real time:\n{}",
                said.join("\n")
            ));
        }
    }

    // Every block carried the model's correction: the first waited for the PT100's first reading
    // (a block sent before it would carry none: 7 µm of scale error at X350).
    let box_line = box_err
        .lines()
        .find(|l| l.contains("blocks sent;"))
        .unwrap_or_else(|| panic!("no transfer summary:\n{box_err}"));
    eprintln!("{box_line}");
    assert!(
        box_line.contains(" 0 block(s) with the held correction"),
        "{box_err}"
    );
    let dnc_line = b_err
        .lines()
        .find(|l| l.starts_with("hil-sim: dnc:"))
        .unwrap_or_else(|| panic!("no DNC summary:\n{b_err}"));
    assert!(!b_err.contains("program stopped"), "{b_err}");
    let e_shift = part_errors_um(&a_dir.join("out/dwell_ends.csv"));
    let e_dnc = part_errors_um(&b_dir.join("out/dwell_ends.csv"));
    let e_frozen = part_errors_um(&c_dir.join("out/dwell_ends.csv"));
    for e in [&e_shift, &e_dnc, &e_frozen] {
        assert_eq!(e.len(), STROKES, "every dwell executed once");
    }
    // The box's hold (`lead_blocks = 1`), not the control's XOFF, paced the transfer: without it
    // the 5-line buffer filled to 4 and said XOFF ≈ 150 times; an XOFF, if any, was followed by XON.
    // The hold does not apply to the set-up lines before the first stroke (no motion: estimated
    // to take no time), so a simulator that reads them late (starved) may see them as one burst
    // and say XOFF once; the fill is reported, the XOFF count is what is asserted.
    let events = std::fs::read_to_string(b_dir.join("out/dnc.csv")).unwrap();
    let xoffs = events.lines().filter(|l| l.contains(",xoff,")).count();
    let xons = events.lines().filter(|l| l.contains(",xon,")).count();
    let fill_max = events
        .lines()
        .skip(1)
        .filter_map(|l| l.rsplit(',').next()?.parse::<usize>().ok())
        .max()
        .unwrap();
    eprintln!("DNC buffer fill at most {fill_max} of 5, {xoffs} XOFF");
    // The origin-shift box wrote the PLC (its shifts are in hil-sim's write log).
    let writes = std::fs::read_to_string(a_dir.join("out/plc_writes.csv")).unwrap();
    assert!(writes.lines().count() > 100, "{run_err}");

    let (rms_s, max_s) = summary(&e_shift);
    let (rms_d, max_d) = summary(&e_dnc);
    let (rms_f, max_f) = summary(&e_frozen);
    eprintln!(
        "{dnc_line}\npart error at {} dwell ends (RMS / max, µm): origin shift {rms_s:.2} / \
         {max_s:.2}, live DNC {rms_d:.2} / {max_d:.2}, frozen rewrite {rms_f:.2} / {max_f:.2}",
        e_dnc.len()
    );
    // Where the worst dwells are (a start-up or a one-off fault shows as one stroke).
    let worst = |e: &[f64]| {
        e.iter()
            .enumerate()
            .fold((0, 0.0), |w, (i, &v)| if v > w.1 { (i, v) } else { w })
    };
    eprintln!(
        "worst dwell: origin shift {:?}, live DNC {:?}",
        worst(&e_shift),
        worst(&e_dnc)
    );
    let start: Vec<&str> = events.lines().take(40).collect();
    assert!(
        xoffs <= 3 && xons + 1 >= xoffs && dnc_line.contains(" 0 overrun(s)"),
        "{dnc_line}\nthe simulators' worst lag behind real time (ms, below the void bar): {lags:?}\n\
         the first events:\n{}",
        start.join("\n")
    );
    // Issue 38: DNC within 1.5× of the origin shift. Each block is held until the one before it
    // runs (`lead_blocks = 1`), so a stroke is compensated ≈ 8 s (simulated) before it ends while
    // the growth drifts by up to 0.06 µm/s; the block carries the correction predicted for its end
    // (`predict_drift`). RMS: measured 0.22 / 0.22 µm idle, 0.23–0.26 / 0.21 with both cores busy
    // (without the prediction 0.38 / 0.21, 1.8×). The largest error is a start-up stroke, sent
    // before the PT100 showed its first 0.1 °C step, so no slope was there to extrapolate: 0.69 vs
    // 0.63 µm idle but 0.97–1.05 vs 0.55–0.63 busy (≤ 1.8×): the max keeps the earlier 2.5×
    // (docs/dnc.md).
    assert!(
        rms_d <= 1.5 * rms_s && max_d <= 2.5 * max_s,
        "live DNC {rms_d:.2} / {max_d:.2} µm vs origin shift {rms_s:.2} / {max_s:.2} µm"
    );
    // The frozen rewrite knows the geometry only: the growth (3 µm/K × up to ≈ 11 K) stays.
    assert!(
        rms_f >= 5.0 * rms_d.max(rms_s) && max_f >= 25.0,
        "DNC {rms_d:.2} µm, origin shift {rms_s:.2} µm vs frozen {rms_f:.2} µm"
    );
    Ok(())
}

#[test]
fn a_lag_is_read_from_hil_sims_episode_lines() {
    let ok = "hil-sim: behind real time started at t = 3.000 s (lag 60.0 ms)\n\
              hil-sim: behind real time cleared at t = 4.000 s (lasted 0.500 s; max lag so far 120.5 ms)";
    assert!((worst_lag_ms(ok) - 120.5).abs() < 1e-9);
    assert!(worst_lag_ms("hil-sim: dnc: 457 lines received").abs() < 1e-9);
    let open = "hil-sim: behind real time started at t = 3.000 s (lag 60.0 ms)";
    assert!(worst_lag_ms(open).is_infinite());
}
