//! Item 2 (sensor faults on demand) and item 6 (manifest): each fault kind shows up where a consumer
//! sees it — recording cells, Modbus PT100 words, CAN silence — only inside its window; the manifest
//! names the hidden effects with docs/diagnose-json.md ids and parameters.

use crate::sim_common;
use embedded_can::Frame as _;
use hil_sim::World;
use hil_sim::io::IoConfig;
use hil_sim::io::{PT100_BREAK, PT100_OVERRANGE, Publisher};
use hil_sim::recording::run_to_end;
use sim_common::{cfg, col, read_csv};

const FAULTS: &str = r#"
[program]
script = [{ t_s = 0.0, x_mm = 0.0, y_mm = 0.0, z_mm = 0.0 }, { t_s = 4.0, x_mm = 40.0, y_mm = 0.0, z_mm = 0.0 }]
[hidden.thermal]
ambient_drift_C_per_h = 360.0
nodes = [{ name = "n", tau_s = 1.0 }]
sensors = [
  { name = "a", node = "ambient", noise_C = 0.01 },
  { name = "b", node = "ambient", noise_C = 0.01 },
  { name = "c", node = "ambient", noise_C = 0.01 },
  { name = "d", node = "ambient", noise_C = 0.01 },
]
[[faults]]
channel = "T_a_C"
kind = "stuck"
from_s = 1.0
to_s = 2.0
[[faults]]
channel = "T_b_C"
kind = "dropout"
from_s = 1.0
to_s = 2.0
[[faults]]
channel = "T_c_C"
kind = "nan"
from_s = 1.0
to_s = 2.0
[[faults]]
channel = "T_d_C"
kind = "spike"
from_s = 1.0
to_s = 2.0
spike_size = 40.0
spike_every_s = 0.1
"#;

fn in_window(t: f64) -> bool {
    (1.0..=2.0).contains(&t)
}

#[test]
fn fault_kinds_in_the_recording() {
    let mut w = World::new(cfg(FAULTS)).unwrap();
    let (bytes, _) = run_to_end(&mut w, Vec::new(), |_| {}).unwrap();
    let (h, rows) = read_csv(&bytes);
    let (t, a, b, c, d) = (
        col(&h, "t_s"),
        col(&h, "T_a_C"),
        col(&h, "T_b_C"),
        col(&h, "T_c_C"),
        col(&h, "T_d_C"),
    );
    let mut stuck_values = std::collections::BTreeSet::new();
    let (mut spikes, mut outside) = (0, 0);
    for r in &rows {
        let ts: f64 = r[t].parse().unwrap();
        if in_window(ts) {
            stuck_values.insert(r[a].clone());
            assert_eq!(r[b], "", "dropout leaves the cell empty at {ts}");
            assert_eq!(r[c], "NaN");
            let dv: f64 = r[d].parse().unwrap();
            let av_true = 20.0 + ts * 0.1; // 360 °C/h = 0.1 °C/s ambient drift
            if dv - av_true > 30.0 {
                spikes += 1;
            }
        } else {
            outside += 1;
            for k in [a, b, c, d] {
                let v: f64 = r[k].parse().unwrap();
                assert!(
                    (v - (20.0 + ts * 0.1)).abs() < 0.1,
                    "healthy outside the window: {v} at {ts}"
                );
            }
        }
    }
    assert_eq!(
        stuck_values.len(),
        1,
        "stuck holds one value while the ambient drifts 0.1 °C"
    );
    assert!(
        (3..30).contains(&spikes),
        "{spikes} spikes (Poisson, mean 10)"
    );
    assert!(outside > 200);
}

#[test]
fn fault_kinds_on_the_buses() {
    let mut w = World::new(cfg(FAULTS)).unwrap();
    let io: IoConfig = toml::from_str(
        "[modbus]\ntemps_first_input = 0\n[can]\nbackend = \"mem\"\ntemp_node = 10\n",
    )
    .unwrap();
    let mut p = Publisher::new(io, &w);
    let (mut saw_break, mut can_silent_in_window, mut can_outside) = (false, true, 0);
    while !w.done() {
        w.tick();
        let out = p.poll(&mut w);
        let t = w.t_s();
        if let Some((_, words)) = out.input_regs.first()
            && in_window(t - 0.0005)
            && in_window(t + 0.0005)
        {
            assert_eq!(words[1], PT100_BREAK, "dropout → sensor break");
            assert_eq!(words[2], PT100_OVERRANGE, "NaN → over-range");
            saw_break = true;
        }
        let temp_frames = out.frames.iter().filter(|f| f.raw_id() == 0x18A).count();
        if in_window(t - 0.0005) && in_window(t + 0.0005) {
            can_silent_in_window &= temp_frames == 0;
        } else {
            can_outside += temp_frames;
        }
    }
    assert!(saw_break);
    assert!(
        can_silent_in_window,
        "the TPDO carrying a dropped-out sensor is not sent"
    );
    assert!(can_outside > 20);
}

#[test]
fn manifest_names_effects_with_design_ids_and_params() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/mill.toml");
    let w = World::new(hil_sim::SimConfig::from_toml_path(&path).unwrap()).unwrap();
    let m = w.manifest();
    let effects = m["effects"].as_array().unwrap();
    let find = |id: &str, axis: &str| {
        effects
            .iter()
            .find(|e| e["effect"] == id && e["axis"] == axis)
            .unwrap_or_else(|| panic!("{id} on {axis} missing: {effects:#?}"))
    };
    assert_eq!(find("backlash", "y")["params"]["b_um"], -5.0);
    assert_eq!(
        find("reversal_profile", "x")["params"]["table_pos_mm_b_um"][1][1],
        -9.0
    );
    assert_eq!(find("cyclic_error", "x")["params"]["period_mm"], 5.0);
    let lag = find("thermal_lag", "z");
    assert_eq!(lag["params"]["um_per_K"], -6.0);
    assert_eq!(lag["sensors"][0]["sensor"], "T_spindle_C");
    assert_eq!(find("thermal_expansion", "x")["params"]["ppm_per_K"], 11.5);
    let f = find("force_deflection", "z");
    assert_eq!(
        (
            f["params"]["channel"].as_str(),
            f["params"]["um_per_N"].as_f64()
        ),
        (Some("F_cut_N"), Some(-0.004))
    );
    assert!(
        (find("servo_lag", "x")["params"]["ms"].as_f64().unwrap() - 1000.0 / 30.0).abs() < 1e-9
    );
    assert_eq!(m["seed"], 7);
}

#[test]
fn recordings_read_back_with_the_projects_reader_and_fault_rows_are_reported() {
    use retrocomp_model::recording::Recording;
    // Faults on: exactly the faulted rows are bad (with their line and column), none silently lost.
    let mut w = World::new(cfg(FAULTS)).unwrap();
    let (bytes, rows) = run_to_end(&mut w, Vec::new(), |_| {}).unwrap();
    let (rec, bad) = Recording::read_lenient(&bytes[..], "faults.csv").unwrap();
    assert_eq!(rec.n_rows() + bad.len(), rows as usize);
    let in_window_rows = (0..rows).filter(|i| in_window(*i as f64 * 0.01)).count();
    assert_eq!(
        bad.len(),
        in_window_rows,
        "every row inside the dropout/NaN window, no other"
    );
    assert!(
        bad.iter().all(|b| b.column.as_deref() == Some("T_b_C")),
        "first bad cell is the dropout: {:?}",
        bad[0]
    );
    // Faults off: the strict reader takes the whole file.
    let clean = FAULTS.split("[[faults]]").next().unwrap();
    let mut w = World::new(cfg(clean)).unwrap();
    let (bytes, rows) = run_to_end(&mut w, Vec::new(), |_| {}).unwrap();
    let rec = Recording::read_strict(&bytes[..], "clean.csv").unwrap();
    assert_eq!(rec.n_rows() as u64, rows);
    assert_eq!(rec.temperature_channels().len(), 4);
}

#[test]
fn encoder_faults_freeze_or_silence_the_tpdo_and_faults_can_be_injected_at_run_time() {
    let toml = r#"
[program]
script = [{ t_s = 0.0, x_mm = 0.0, y_mm = 0.0, z_mm = 0.0 }, { t_s = 1.0, x_mm = 10.0, y_mm = 0.0, z_mm = 0.0 }]
[[faults]]
channel = "enc_x"
kind = "stuck"
from_s = 0.3
to_s = 0.5
"#;
    let mut w = World::new(cfg(toml)).unwrap();
    let io: IoConfig =
        toml::from_str("[can]\nbackend = \"mem\"\nencoder_period_s = 0.01\n").unwrap();
    let mut p = Publisher::new(io, &w);
    let bad = hil_sim::config::FaultConfig {
        channel: "enc_q".into(),
        kind: hil_sim::physics::faults::FaultKind::Dropout,
        from_s: 0.0,
        to_s: 1.0,
        spike_size: 0.0,
        spike_every_s: 1.0,
    };
    assert!(
        w.inject_fault(bad.clone())
            .unwrap_err()
            .to_string()
            .contains("enc_q")
    );
    w.inject_fault(hil_sim::config::FaultConfig {
        channel: "enc_y".into(),
        from_s: 0.6,
        to_s: 0.8,
        ..bad
    })
    .unwrap();
    let (mut stuck_raw, mut y_in_window, mut y_outside, mut x_moving_outside) =
        (Vec::new(), 0, 0, Vec::new());
    while !w.done() {
        w.tick();
        let t = w.t_s();
        for f in p.poll(&mut w).frames {
            let raw = u32::from_le_bytes(f.data()[..4].try_into().unwrap());
            match f.raw_id() {
                0x181 if (0.3..=0.5).contains(&t) => stuck_raw.push(raw),
                0x181 => x_moving_outside.push(raw),
                0x182 if (0.6..=0.8).contains(&t) => y_in_window += 1,
                0x182 => y_outside += 1,
                _ => {}
            }
        }
    }
    assert!(
        stuck_raw.len() >= 15 && stuck_raw.iter().all(|r| *r == stuck_raw[0]),
        "x frozen while moving: {stuck_raw:?}"
    );
    assert!(
        x_moving_outside.windows(2).any(|w| w[1] > w[0]),
        "x counts move outside the window"
    );
    assert_eq!(y_in_window, 0, "y silent during the injected dropout");
    assert!(y_outside > 50);
}
