//! The ISO 230-4 polar plot of a circular test: the measured path of each direction on a polar grid,
//! its radial deviation Δr magnified about the nominal circle (display radius ρ = 1 + k·Δr, one grid
//! ring per `ring_um`; the magnification is printed), start points marked, G, G(b), F and the
//! circular hysteresis H beside the plot; feed and radius in the title.
//! Angles θ in rad from +X towards +Y; Δr = measured − nominal radius, µm (as [`super::circular`]).

use std::f64::consts::TAU;

use plotters::prelude::*;

use super::chart::{LEGEND_FRAME, PALETTE, PANEL_PX, wrap};
use super::circular::{CircleReport, CircleTrace, Rotation};
use super::numeric::px;
use super::report::PlotError;

/// Display units of one grid ring (the nominal circle has radius 1).
const RING_UNITS: f64 = 0.12;
const SIZE_PX: u32 = 600;

/// Circular hysteresis H (ISO 230-4): the largest radial difference between the CCW and CW paths at
/// the same angle, µm; `None` unless both directions were measured. CW is interpolated linearly (in
/// angle, wrapped to one turn) at each CCW sample; a common centre offset cancels in the difference.
pub fn hysteresis_um(traces: &[CircleTrace]) -> Option<f64> {
    let ccw = traces.iter().find(|t| t.rotation == Rotation::Ccw)?;
    let cw = traces.iter().find(|t| t.rotation == Rotation::Cw)?;
    let mut pts: Vec<(f64, f64)> = cw
        .angle_rad
        .iter()
        .map(|a| a.rem_euclid(TAU))
        .zip(cw.dr_um.iter().copied())
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.dedup_by(|a, b| (a.0 - b.0).abs() < 1e-12);
    if pts.len() < 2 {
        return None;
    }
    // One turn with a wrapped point at each end, so every angle in [0, 2π) has neighbours.
    let (first, last) = (pts[0], pts[pts.len() - 1]);
    pts.insert(0, (last.0 - TAU, last.1));
    pts.push((first.0 + TAU, first.1));
    let at = |th: f64| {
        let th = th.rem_euclid(TAU);
        let i = pts.partition_point(|p| p.0 <= th).clamp(1, pts.len() - 1);
        let (a, b) = (pts[i - 1], pts[i]);
        a.1 + (b.1 - a.1) * (th - a.0) / (b.0 - a.0)
    };
    ccw.angle_rad
        .iter()
        .zip(&ccw.dr_um)
        .map(|(th, dr)| (dr - at(*th)).abs())
        .reduce(f64::max)
}

/// A "nice" ring step (1, 2 or 5 × 10ⁿ µm) so that the largest |Δr| spans at most four rings.
pub fn ring_step_um(max_abs_um: f64) -> f64 {
    let target = (max_abs_um / 3.5).max(1e-3);
    let p = 10f64.powf(target.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= target)
        .unwrap_or(10.0 * p)
}

fn colour(r: Rotation) -> RGBColor {
    match r {
        Rotation::Ccw => PALETTE[0],
        Rotation::Cw => PALETTE[1],
    }
}

/// The figure's numbers, one line each.
pub fn notes(rep: &CircleReport, traces: &[CircleTrace], ring_um: f64) -> Vec<String> {
    let mag = RING_UNITS * rep.radius_mm * 1e3 / ring_um;
    let mut n: Vec<String> = rep
        .iso230_4
        .g_um
        .iter()
        .map(|(k, g)| format!("G ({k}) = {g:.2} µm"))
        .collect();
    if let Some(g) = rep.iso230_4.g_bidirectional_um {
        n.push(format!("G(b) = {g:.2} µm"));
    }
    match hysteresis_um(traces) {
        Some(h) => n.push(format!("H (circular hysteresis) = {h:.2} µm")),
        None => n.push("H: n/a (needs a CCW and a CW run)".into()),
    }
    n.push(format!(
        "F: max {:.2} µm, min {:.2} µm (nominal centre)",
        rep.iso230_4.f_max_um, rep.iso230_4.f_min_um
    ));
    n.push(format!(
        "error scale: 1 ring = {ring_um} µm (magnification ×{mag:.0} against the radius)"
    ));
    n.push(format!("centre: {}", rep.iso230_4.centre_method));
    n
}

/// Renders the polar plot.
pub fn svg(rep: &CircleReport, traces: &[CircleTrace]) -> Result<String, PlotError> {
    let title = format!(
        "{} circular test, R = {} mm, F = {} mm/min",
        rep.standard, rep.radius_mm, rep.feed_mm_per_min
    );
    let all = || traces.iter().flat_map(|t| t.angle_rad.iter().zip(&t.dr_um));
    if all().next().is_none() {
        return Err(PlotError::Empty(title));
    }
    if all().any(|(a, d)| !a.is_finite() || !d.is_finite()) {
        return Err(PlotError::NonFinite(title));
    }
    let max_abs = all().map(|(_, d)| d.abs()).fold(0.0, f64::max);
    let ring_um = ring_step_um(max_abs);
    let notes = notes(rep, traces, ring_um);
    let mut out = String::new();
    draw(&mut out, &title, traces, ring_um, &notes)
        .map_err(|e| PlotError::Draw(title.clone(), e))?;
    Ok(out)
}

type DrawResult<T> = Result<T, Box<dyn std::error::Error + Send + Sync>>;

fn draw(
    out: &mut String,
    title: &str,
    traces: &[CircleTrace],
    ring_um: f64,
    notes: &[String],
) -> DrawResult<()> {
    let k = RING_UNITS / ring_um;
    let rho = |dr: f64| 1.0 + k * dr;
    let root = SVGBackend::with_string(out, (SIZE_PX + PANEL_PX, SIZE_PX)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(title, ("sans-serif", 18))?;
    let (left, panel) = root.split_horizontally(SIZE_PX);
    let (w, h) = left.dim_in_pixel();
    let side = px(w.min(h)) - 20;
    let area = left.shrink(((px(w) - side) / 2, 0), (side, side));
    let lim = 1.0 + 4.6 * RING_UNITS;
    let mut chart = ChartBuilder::on(&area).build_cartesian_2d(-lim..lim, -lim..lim)?;
    let grey = RGBColor(200, 200, 200);
    let circle = |r: f64| {
        (0..=180).map(move |i| {
            let a = TAU * f64::from(i) / 180.0;
            (r * a.cos(), r * a.sin())
        })
    };
    for ring in -4..=4 {
        let r = 1.0 + f64::from(ring) * RING_UNITS;
        let style = if ring == 0 {
            RGBColor(90, 90, 90).stroke_width(2)
        } else {
            grey.stroke_width(1)
        };
        chart.draw_series(std::iter::once(PathElement::new(
            circle(r).collect::<Vec<_>>(),
            style,
        )))?;
        if ring != 0 && ring % 2 == 0 {
            let a = 100f64.to_radians();
            chart.draw_series(std::iter::once(Text::new(
                format!("{:+} µm", f64::from(ring) * ring_um),
                (r * a.cos(), r * a.sin()),
                ("sans-serif", 11)
                    .into_font()
                    .color(&RGBColor(110, 110, 110)),
            )))?;
        }
    }
    for deg in (0..360).step_by(30) {
        let a = f64::from(deg).to_radians();
        let (r0, r1) = (1.0 - 4.0 * RING_UNITS, lim * 0.97);
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(r0 * a.cos(), r0 * a.sin()), (r1 * a.cos(), r1 * a.sin())],
            grey.stroke_width(1),
        )))?;
        chart.draw_series(std::iter::once(Text::new(
            format!("{deg}°"),
            (0.5 * a.cos() - 0.05, 0.5 * a.sin()),
            ("sans-serif", 11)
                .into_font()
                .color(&RGBColor(110, 110, 110)),
        )))?;
    }
    for t in traces {
        let c = colour(t.rotation);
        let pts: Vec<(f64, f64)> = t
            .angle_rad
            .iter()
            .zip(&t.dr_um)
            .map(|(a, d)| (rho(*d) * a.cos(), rho(*d) * a.sin()))
            .collect();
        chart.draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))?;
        if let Some(p) = pts.first() {
            chart.draw_series(std::iter::once(Circle::new(*p, 6, c.filled())))?;
        }
    }
    draw_panel(&panel, traces, notes)?;
    root.present()?;
    Ok(())
}

fn draw_panel<DB: DrawingBackend>(
    panel: &DrawingArea<DB, plotters::coord::Shift>,
    traces: &[CircleTrace],
    notes: &[String],
) -> DrawResult<()>
where
    DB::ErrorType: 'static,
{
    let font = ("sans-serif", 13).into_font();
    let (w, _) = panel.dim_in_pixel();
    let mut y = 24;
    for t in traces {
        let c = colour(t.rotation);
        let name = format!("{:?}", t.rotation).to_uppercase();
        panel.draw(&Rectangle::new([(12, y - 1), (34, y + 2)], c.filled()))?;
        panel.draw(&Text::new(
            format!("{name} path"),
            (40, y - 7),
            font.clone(),
        ))?;
        y += 20;
        panel.draw(&Rectangle::new([(19, y - 4), (27, y + 4)], c.filled()))?;
        panel.draw(&Text::new(
            format!("{name} start"),
            (40, y - 7),
            font.clone(),
        ))?;
        y += 20;
    }
    panel.draw(&Rectangle::new(
        [(4, 8), (px(w) - 6, y - 8)],
        LEGEND_FRAME.stroke_width(1),
    ))?;
    y += 14;
    for note in notes {
        for line in wrap(note, 34) {
            panel.draw(&Text::new(line, (8, y - 7), font.clone()))?;
            y += 16;
        }
        y += 4;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(rotation: Rotation, f: impl Fn(f64) -> f64) -> CircleTrace {
        let angle_rad: Vec<f64> = (0..360).map(|i| f64::from(i).to_radians()).collect();
        let dr_um = angle_rad.iter().map(|a| f(*a)).collect();
        CircleTrace {
            rotation,
            angle_rad,
            dr_um,
        }
    }

    #[test]
    fn hysteresis_is_the_largest_gap_between_directions() {
        let ccw = trace(Rotation::Ccw, |a| 3.0 * a.cos());
        let cw = trace(Rotation::Cw, |a| 3.0 * a.cos() + 1.5 * (2.0 * a).sin());
        let h = hysteresis_um(&[ccw.clone(), cw]).unwrap();
        assert!((h - 1.5).abs() < 0.01, "H = {h}");
        assert_eq!(hysteresis_um(&[ccw]), None);
    }

    #[test]
    fn ring_steps_are_nice_and_cover_the_data() {
        assert_eq!(ring_step_um(7.0), 2.0);
        assert_eq!(ring_step_um(30.0), 10.0);
        for m in [0.3, 4.0, 17.0, 260.0] {
            assert!(4.0 * ring_step_um(m) >= m);
        }
    }
}
