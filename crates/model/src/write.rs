//! [`ModelSpec`] → TOML text in canonical units (µm, µrad, mm, °C), readable by `parse.rs`.
//! Numbers are written with Rust's shortest round-trip form, so write → read gives the same spec.

use std::fmt::Write;

use super::function::ErrorFunction;
use super::spec::*;

fn num(x: f64) -> String {
    // `{:?}` is the shortest representation that reads back to the same f64, and is valid TOML.
    format!("{x:?}")
}

fn arr(xs: &[f64]) -> String {
    let parts: Vec<String> = xs.iter().map(|&x| num(x)).collect();
    format!("[{}]", parts.join(", "))
}

fn mat(rows: &[Vec<f64>]) -> String {
    let parts: Vec<String> = rows.iter().map(|r| arr(r)).collect();
    format!("[{}]", parts.join(", "))
}

fn string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 || c as u32 == 0x7f => {
                let _ = write!(out, "\\u{:04X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn strings(xs: &[String]) -> String {
    let parts: Vec<String> = xs.iter().map(|s| string(s)).collect();
    format!("[{}]", parts.join(", "))
}

/// Write a function's keys with value unit suffix `unit` (e.g. `um`, `urad`, `um_per_N`).
fn function(out: &mut String, f: &ErrorFunction, unit: &str, kind_key: &str) {
    match f {
        ErrorFunction::Table(t) => {
            let _ = writeln!(out, "{kind_key} = \"table\"");
            let _ = writeln!(out, "interpolation = \"{}\"", t.interpolation.as_str());
            let _ = writeln!(out, "positions_mm = {}", arr(&t.positions_mm));
            let _ = writeln!(out, "forward_{unit} = {}", arr(&t.forward));
            if t.is_bidirectional() {
                let _ = writeln!(out, "reverse_{unit} = {}", arr(&t.reverse));
            }
        }
        ErrorFunction::Polynomial {
            coefficients,
            range_mm,
        } => {
            let _ = writeln!(out, "{kind_key} = \"polynomial\"");
            let _ = writeln!(out, "coefficients_{unit} = {}", arr(coefficients));
            if let Some((a, b)) = range_mm {
                let _ = writeln!(out, "range_mm = {}", arr(&[*a, *b]));
            }
        }
        ErrorFunction::PiecewiseQuadratic {
            base,
            knots_mm,
            knot_coefficients,
            range_mm,
        } => {
            let _ = writeln!(out, "{kind_key} = \"piecewise_quadratic\"");
            let _ = writeln!(out, "coefficients_{unit} = {}", arr(base));
            let _ = writeln!(out, "knots_mm = {}", arr(knots_mm));
            let _ = writeln!(out, "knot_coefficients_{unit} = {}", arr(knot_coefficients));
            if let Some((a, b)) = range_mm {
                let _ = writeln!(out, "range_mm = {}", arr(&[*a, *b]));
            }
        }
    }
}

pub(crate) fn write_model(s: &ModelSpec) -> String {
    let mut o = String::new();
    write_machine(&mut o, s);
    for a in &s.axes {
        let _ = writeln!(o, "\n[axes.{}]", a.axis);
        let _ = writeln!(o, "offset_mm = {}", arr(&a.offset_mm));
        if let Some((lo, hi)) = a.travel_mm {
            let _ = writeln!(o, "travel_mm = {}", arr(&[lo, hi]));
        }
    }
    for t in &s.tools {
        let _ = writeln!(
            o,
            "\n[[tools]]\nname = {}\noffset_mm = {}",
            string(&t.name),
            arr(&t.offset_mm)
        );
    }
    for c in &s.components {
        let _ = writeln!(o, "\n[[components]]\nname = \"{}\"", c.id.iso_name());
        function(
            &mut o,
            &c.function,
            if c.id.is_rotation() { "urad" } else { "um" },
            "kind",
        );
    }
    for q in &s.squareness {
        let _ = writeln!(
            o,
            "\n[[squareness]]\nname = \"{}\"\non_axis = \"{}\"\nvalue_urad = {}",
            q.kind.iso_name(),
            q.on_axis,
            num(q.value_urad)
        );
    }
    for x in &s.sensors {
        write_sensor(&mut o, x);
    }
    for th in &s.thermal {
        write_thermal(&mut o, th);
    }
    for f in &s.forces {
        let _ = writeln!(o, "\n[[forces]]\nname = {}", string(&f.name));
        if let Some(src) = &f.from_strain {
            let _ = writeln!(
                o,
                "strain = {}\ngain_N_per_ue = {}\noffset_ue = {}",
                string(&src.strain),
                num(src.gain_n_per_ue),
                num(src.offset_ue)
            );
        }
    }
    for l in &s.load {
        write_load(&mut o, l);
    }
    if let Some(ls) = &s.lag_state {
        write_lag_state(&mut o, ls);
    }
    o
}

/// The header and `[machine]`: what names the machine and orders its chain.
fn write_machine(o: &mut String, s: &ModelSpec) {
    let _ = writeln!(
        o,
        "# retrocomp machine model (canonical units: mm, µm, µrad, °C, s, N)"
    );
    let _ = writeln!(o, "schema = 1\n\n[machine]");
    let _ = writeln!(o, "name = {}", string(&s.name));
    if !s.description.is_empty() {
        let _ = writeln!(o, "description = {}", string(&s.description));
    }
    if s.synthetic {
        let _ = writeln!(o, "synthetic = true");
    }
    let _ = writeln!(o, "chain = {}", string(&s.chain_string()));
    let sign = if s.tool_axis.1 < 0.0 { "-" } else { "+" };
    let _ = writeln!(o, "tool_axis = \"{sign}{}\"", s.tool_axis.0);
}

/// One `[[sensors]]` entry; the optional keys only when set, so a read gives back `None`.
fn write_sensor(o: &mut String, x: &SensorSpec) {
    let _ = writeln!(
        o,
        "\n[[sensors]]\nname = {}\nreference_C = {}",
        string(&x.name),
        num(x.reference_c)
    );
    if let Some(tau) = x.tau_s {
        let _ = writeln!(o, "tau_s = {}", num(tau));
    }
    if let Some(c) = &x.column {
        let _ = writeln!(o, "column = {}", string(c));
    }
    if let Some(p) = x.exponent {
        let _ = writeln!(o, "exponent = {}", num(p));
    }
}

/// One `[[thermal]]` term, its coefficient keys suffixed with the target's unit (µm or µrad).
fn write_thermal(o: &mut String, th: &ThermalSpec) {
    let u = if th.target.is_rotation() {
        "urad"
    } else {
        "um"
    };
    let _ = writeln!(
        o,
        "\n[[thermal]]\nname = {}\ntarget = \"{}\"",
        string(&th.name),
        th.target.iso_name()
    );
    match &th.kind {
        ThermalKind::PolynomialDt {
            sensors,
            e0,
            b_per_k,
            c_per_k2,
        } => {
            let _ = writeln!(
                o,
                "kind = \"polynomial_dt\"\nsensors = {}\ne0_{u} = {}",
                strings(sensors),
                num(*e0)
            );
            let _ = writeln!(o, "b_{u}_per_K = {}", arr(b_per_k));
            if !c_per_k2.is_empty() {
                let _ = writeln!(o, "c_{u}_per_K2 = {}", mat(c_per_k2));
            }
        }
        ThermalKind::Slope {
            sensors,
            s0_per_mm,
            s_per_mm_k,
            d_per_mm_k2,
        } => {
            let _ = writeln!(
                o,
                "kind = \"slope\"\nsensors = {}\ns0_{u}_per_m = {}",
                strings(sensors),
                num(*s0_per_mm)
            );
            let _ = writeln!(o, "s_{u}_per_m_K = {}", arr(s_per_mm_k));
            if !d_per_mm_k2.is_empty() {
                let _ = writeln!(o, "d_{u}_per_m_K2 = {}", mat(d_per_mm_k2));
            }
        }
        ThermalKind::Expansion {
            sensor,
            alpha_ppm_per_k,
            origin_mm,
            reference_c,
        } => {
            let _ = writeln!(
                o,
                "kind = \"expansion\"\nsensor = {}\nalpha_ppm_per_K = {}\norigin_mm = {}\nreference_C = {}",
                string(sensor),
                num(*alpha_ppm_per_k),
                num(*origin_mm),
                num(*reference_c)
            );
        }
        ThermalKind::Stations {
            along,
            sensors,
            stations_mm,
            e0,
            b_per_k,
        } => {
            let _ = writeln!(
                o,
                "kind = \"stations\"\nalong = \"{along}\"\nsensors = {}",
                strings(sensors)
            );
            let _ = writeln!(
                o,
                "stations_mm = {}\ne0_{u} = {}\nb_{u}_per_K = {}",
                arr(stations_mm),
                arr(e0),
                mat(b_per_k)
            );
        }
    }
}

/// One `[[load]]` term; its function keys carry the unit of the load kind.
fn write_load(o: &mut String, l: &LoadSpec) {
    let _ = writeln!(
        o,
        "\n[[load]]\nname = {}\ntarget = \"{}\"",
        string(&l.name),
        l.target.iso_name()
    );
    let rot = l.target.is_rotation();
    match &l.kind {
        LoadKind::Compliance { force, compliance } => {
            let _ = writeln!(o, "kind = \"compliance\"\nforce = {}", string(force));
            function(
                o,
                compliance,
                if rot { "urad_per_N" } else { "um_per_N" },
                "shape",
            );
        }
        LoadKind::WeightAngular {
            force,
            reference,
            reference_force_n,
            lever_mm,
            load_height_mm,
        } => {
            let _ = writeln!(
                o,
                "kind = \"weight_angular\"\nforce = {}\nreference_force_N = {}\nlever_mm = {}\nload_height_mm = {}",
                string(force),
                num(*reference_force_n),
                num(*lever_mm),
                num(*load_height_mm)
            );
            function(o, reference, if rot { "urad" } else { "um" }, "shape");
        }
    }
}

/// `[lag_state]`: the lags `retrocomp eval` continues from.
fn write_lag_state(o: &mut String, ls: &LagState) {
    let _ = writeln!(
        o,
        "\n# The lags at the last row of the recording this model was fitted on: `retrocomp eval`\n\
         # continues from them when a recording starts after t_s (the gateway ignores them).\n\
         [lag_state]\nt_s = {}",
        num(ls.t_s)
    );
    let items: Vec<String> = ls
        .lagged
        .iter()
        .map(|(n, v)| format!("{} = {}", string(n), num(*v)))
        .collect();
    let _ = writeln!(o, "lagged = {{ {} }}", items.join(", "));
}
