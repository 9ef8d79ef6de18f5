//! The ISO 230-2 figure as the standard draws it: per target, the forward (↑) and reverse (↓) mean
//! deviations x̄i↑, x̄i↓ with their x̄ ± 2s bands, the bidirectional mean x̄i, every reading, and the
//! axis values E, M, B, R, A printed beside the plot (never over the data).
//! Deviation = actual − target, µm; target position in mm.

use super::chart::{Chart, Layout, Series, render};
use super::html::{Block, Section};
use super::iso230_2::{Iso230_2Report, Reading};
use super::report::PlotError;
use super::table::Direction;
use plotters::style::RGBColor;

const FORWARD: RGBColor = RGBColor(31, 119, 180);
const FORWARD_READING: RGBColor = RGBColor(120, 170, 220);
const REVERSE: RGBColor = RGBColor(214, 39, 40);
const REVERSE_READING: RGBColor = RGBColor(240, 140, 140);
const MEAN: RGBColor = RGBColor(90, 90, 90);

/// What the figure draws, in words (the CLI help and the report say the same).
pub const DRAWN: &str = "forward and reverse mean deviations x̄↑, x̄↓ per target with their \
x̄ ± 2s bands (when every target has two or more runs per direction), the bidirectional mean x̄, \
every reading, and E, M, B, R, A with their values beside the plot";

/// The figure's numbers, one line each (also printed in the report's table).
pub fn notes(rep: &Iso230_2Report) -> Vec<String> {
    let a = &rep.axis;
    let na = |name: &str, v: Option<f64>, up: Option<f64>, down: Option<f64>| match v {
        Some(v) => format!(
            "{name} = {v:.2} µm ({name}↑ {:.2}, {name}↓ {:.2})",
            up.unwrap_or(f64::NAN),
            down.unwrap_or(f64::NAN)
        ),
        None => format!("{name}: n/a (fewer than two runs per direction: s undefined)"),
    };
    let worst = rep
        .targets
        .iter()
        .max_by(|p, q| p.reversal_um.abs().total_cmp(&q.reversal_um.abs()));
    let (n_up, n_down) = rep
        .targets
        .iter()
        .fold((usize::MAX, usize::MAX), |(u, d), t| {
            (u.min(t.n_up), d.min(t.n_down))
        });
    vec![
        format!(
            "E = {:.2} µm (E↑ {:.2}, E↓ {:.2})",
            a.e_um, a.e_up_um, a.e_down_um
        ),
        format!("M = {:.2} µm", a.m_um),
        format!(
            "B = {:.2} µm at {} mm (B̄ = {:.2} µm)",
            a.b_um,
            worst.map_or(f64::NAN, |t| t.target_mm),
            a.b_mean_um
        ),
        na("R", a.r_um, a.r_up_um, a.r_down_um),
        na("A", a.a_um, a.a_up_um, a.a_down_um),
        format!(
            "{} targets, runs per direction ≥ {n_up} ↑ / {n_down} ↓",
            rep.targets.len()
        ),
    ]
}

/// Renders the figure; `title` names the machine/axis (the standard's edition is appended).
pub fn svg(
    title: &str,
    rep: &Iso230_2Report,
    readings: &[Reading],
) -> Result<(String, Layout), PlotError> {
    let t = &rep.targets;
    let mut series = vec![];
    let band = |mean: fn(&super::iso230_2::TargetStats) -> f64,
                s: fn(&super::iso230_2::TargetStats) -> Option<f64>,
                sign: f64| {
        t.iter()
            .map(|x| s(x).map(|s| (x.target_mm, mean(x) + sign * 2.0 * s)))
            .collect::<Option<Vec<_>>>()
    };
    if let (Some(lo), Some(hi)) = (
        band(|x| x.mean_up_um, |x| x.s_up_um, -1.0),
        band(|x| x.mean_up_um, |x| x.s_up_um, 1.0),
    ) {
        series.push(Series::band("x̄↑ ± 2s↑ (forward)", lo, hi).with_colour(FORWARD));
    }
    if let (Some(lo), Some(hi)) = (
        band(|x| x.mean_down_um, |x| x.s_down_um, -1.0),
        band(|x| x.mean_down_um, |x| x.s_down_um, 1.0),
    ) {
        series.push(Series::band("x̄↓ ± 2s↓ (reverse)", lo, hi).with_colour(REVERSE));
    }
    let line = |f: fn(&super::iso230_2::TargetStats) -> f64| {
        t.iter().map(|x| (x.target_mm, f(x))).collect::<Vec<_>>()
    };
    series
        .push(Series::line_markers("x̄↑ forward mean", line(|x| x.mean_up_um)).with_colour(FORWARD));
    series.push(
        Series::line_markers("x̄↓ reverse mean", line(|x| x.mean_down_um)).with_colour(REVERSE),
    );
    series.push(Series::line("x̄ bidirectional mean", line(|x| x.mean_um)).with_colour(MEAN));
    for (name, dir, c) in [
        ("readings ↑", Direction::Forward, FORWARD_READING),
        ("readings ↓", Direction::Reverse, REVERSE_READING),
    ] {
        let pts = readings
            .iter()
            .filter(|r| r.direction == dir)
            .map(|r| (r.target_mm, r.deviation_um))
            .collect();
        series.push(Series::markers(name, pts).with_colour(c));
    }
    let notes = notes(rep);
    let title = format!("{title} — {}", rep.standard);
    render(&Chart {
        title: &title,
        x_label: "target position / mm",
        y_label: "deviation (actual − target) / µm",
        series: &series,
        notes: &notes,
        robust_y: false,
    })
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.2}"))
}

/// The report's sections: the figure, the standard's per-target and axis tables, what was assumed.
pub fn sections(rep: &Iso230_2Report, figure_svg: String, assumed: Vec<String>) -> Vec<Section> {
    let head = [
        "target / mm",
        "n↑",
        "n↓",
        "x̄↑ / µm",
        "x̄↓ / µm",
        "x̄ / µm",
        "Bi / µm",
        "s↑ / µm",
        "s↓ / µm",
        "Ri / µm",
    ];
    let rows = rep
        .targets
        .iter()
        .map(|t| {
            vec![
                format!("{:.3}", t.target_mm),
                t.n_up.to_string(),
                t.n_down.to_string(),
                format!("{:.2}", t.mean_up_um),
                format!("{:.2}", t.mean_down_um),
                format!("{:.2}", t.mean_um),
                format!("{:.2}", t.reversal_um),
                opt(t.s_up_um),
                opt(t.s_down_um),
                opt(t.r_um),
            ]
        })
        .collect();
    let a = &rep.axis;
    let axis_rows = vec![
        vec![
            "E (E↑, E↓)".into(),
            format!("{:.2} ({:.2}, {:.2})", a.e_um, a.e_up_um, a.e_down_um),
        ],
        vec!["M".into(), format!("{:.2}", a.m_um)],
        vec![
            "B (B̄)".into(),
            format!("{:.2} ({:.2})", a.b_um, a.b_mean_um),
        ],
        vec![
            "R (R↑, R↓)".into(),
            format!("{} ({}, {})", opt(a.r_um), opt(a.r_up_um), opt(a.r_down_um)),
        ],
        vec![
            "A (A↑, A↓)".into(),
            format!("{} ({}, {})", opt(a.a_um), opt(a.a_up_um), opt(a.a_down_um)),
        ],
    ];
    let mut assumed = assumed;
    assumed.extend(rep.note.clone());
    vec![
        Section {
            heading: "Figure".into(),
            blocks: vec![Block::Figure {
                svg: figure_svg,
                caption: format!("Drawn: {DRAWN}."),
            }],
        },
        Section {
            heading: format!("{} axis values", rep.standard),
            blocks: vec![Block::Table {
                head: vec!["value".into(), "µm".into()],
                rows: axis_rows,
            }],
        },
        Section {
            heading: "Per target".into(),
            blocks: vec![Block::Table {
                head: head.iter().map(|h| h.to_string()).collect(),
                rows,
            }],
        },
        Section {
            heading: "What was assumed".into(),
            blocks: vec![Block::List(assumed)],
        },
    ]
}
