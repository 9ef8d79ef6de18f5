use super::*;
use crate::demo::metrics::{ErrorTrace, Phase};
use retrocomp_analysis::chart_geometry::parse;

/// A run of `mode` over 40 s at 20 ms: the uncompensated error climbs to ≈ 55 µm, the geometric
/// one to ≈ 48, the full and fitted ones stay within 0.3–2.6 µm (the shape of a real demo run).
fn run(mode: Mode) -> RunResult {
    let t_s: Vec<f64> = (0..2000).map(|i| f64::from(i) * 0.02).collect();
    let e_um = t_s
        .iter()
        .map(|t| {
            let wave = (t * 1.3).sin();
            let v = match mode {
                Mode::Uncompensated => 55.0 * (t / 40.0) + 2.0 * wave,
                Mode::Geometric => 48.0 * (t / 40.0),
                Mode::Full => 1.4 + 1.1 * wave,
                Mode::Fitted => 1.5 + 1.05 * (t * 1.1).cos(),
            };
            [v * 0.3, v * 0.1, -v * 0.9]
        })
        .collect();
    let phase = |name, from_s, to_s| Phase { name, from_s, to_s };
    RunResult {
        mode,
        stats: Default::default(),
        trace: ErrorTrace {
            t_s,
            e_um,
            phases: vec![
                phase("warm-up", 1.0, 22.5),
                phase("cut", 22.5, 33.2),
                phase("cool-down", 33.5, 39.98),
            ],
        },
        gateway_cycles: 0,
        writes_ok: 0,
        gateway: Default::default(),
    }
}

#[test]
fn second_panel_follows_the_full_and_fitted_runs_and_phases_are_marked() {
    let runs: Vec<RunResult> = Mode::ALL.iter().map(|m| run(*m)).collect();
    let figs = figures(&runs).unwrap();
    let names: Vec<&str> = figs.iter().map(|f| f.0.as_str()).collect();
    assert_eq!(
        names,
        [
            "error_x.svg",
            "error_y.svg",
            "error_z.svg",
            "volumetric.svg"
        ]
    );
    for (k, (name, svg, layout)) in figs.iter().enumerate() {
        let value = |e: &[f64; 3]| match k {
            3 => (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt(),
            _ => e[k],
        };
        let range = |modes: &[Mode]| {
            let vals = runs
                .iter()
                .filter(|r| modes.contains(&r.mode))
                .flat_map(|r| r.trace.e_um.iter().map(value));
            vals.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            })
        };
        let (all, detail) = (range(&Mode::ALL), range(&DETAIL_RUNS));
        assert_eq!(layout.panels.len(), 2, "{name}");
        let inside = |r: (f64, f64), d: (f64, f64)| r.0 <= d.0 && r.1 >= d.1;
        let (top, low) = (layout.panels[0].y_range, layout.panels[1].y_range);
        assert!(inside(top, all), "{name}: top panel {top:?}, data {all:?}");
        // The second panel holds every full and fitted value, and its scale is theirs (padded by
        // the chart's 5 %), not the uncompensated run's.
        assert!(
            inside(low, detail),
            "{name}: second panel {low:?}, data {detail:?}"
        );
        let span = detail.1 - detail.0;
        assert!(
            low.1 - low.0 <= 1.15 * span,
            "{name}: second panel {low:?} for full/fitted data {detail:?}"
        );
        assert!(
            (low.1 - low.0) * 5.0 < top.1 - top.0,
            "{name}: {low:?} vs {top:?}"
        );
        assert_eq!(layout.panels[1].beyond_scale, 0, "{name}");
        // Three phase bands in time order, where the x scale puts their times, over both panels.
        let [l, _, r, _] = layout.panels[1].plot_px;
        let (x0, x1) = layout.x_range;
        let px = |t: f64| f64::from(l) + (t - x0) / (x1 - x0) * f64::from(r - l);
        assert_eq!(layout.spans_px.len(), 3, "{name}");
        for (b, (from, to)) in
            layout
                .spans_px
                .iter()
                .zip([(1.0, 22.5), (22.5, 33.2), (33.5, 39.98)])
        {
            assert!(
                (f64::from(b[0]) - px(from)).abs() <= 2.0
                    && (f64::from(b[2]) - px(to)).abs() <= 2.0,
                "{name}: band {b:?} for {from}..{to} s"
            );
            assert!(b[1] < layout.panels[0].plot_px[1] && b[3] >= layout.panels[1].plot_px[3] - 1);
        }
        for label in [
            "warm-up",
            "cut",
            "cool-down",
            "(full, fitted)",
            "largest |value| per run",
        ] {
            assert!(svg.contains(label), "{name}: no {label}");
        }
        // One legend box, beside the panels, over no curve.
        let g = parse(svg);
        assert_eq!(g.legend_boxes.len(), 1, "{name}");
        assert!(layout.legend_px[0] > layout.panels[0].plot_px[2]);
        assert!(g.data_points.len() > 4 * 2000, "{name}");
        assert!(g.covered().is_empty(), "{name}: {:?}", g.covered());
    }
}

#[test]
fn a_recording_without_phases_still_plots() {
    let mut runs: Vec<RunResult> = Mode::ALL.iter().map(|m| run(*m)).collect();
    for r in &mut runs {
        r.trace.phases.clear();
    }
    for (name, svg, layout) in figures(&runs).unwrap() {
        assert!(
            layout.spans_px.is_empty() && !svg.contains("warm-up"),
            "{name}"
        );
        assert_eq!(layout.panels.len(), 2);
    }
}
