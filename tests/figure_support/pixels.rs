//! No legend box covers data, checked twice on every figure a test writes: from the figure's own
//! geometry (`analysis::chart_geometry`: the legend box, its swatches, every data point and the
//! colours the data were drawn in) and on its pixels: the SVG is rendered to PNG by rsvg-convert
//! (Debian librsvg2-bin, scripts/setup-peers.sh) at its own size, and the legend box — less its
//! swatches — must hold no pixel of a series colour, while the plot area holds them.
//! Grey series colours (r = g = b) are left to the geometric check: anti-aliased black text is
//! grey too. Included by the `analysis` and `diagnose` test binaries, each using part of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use retrocomp_analysis::chart_geometry::{self, BoxPx, SvgGeometry};

fn rsvg_convert() -> PathBuf {
    let p = PathBuf::from(
        std::env::var("RETROCOMP_RSVG_CONVERT").unwrap_or("/usr/bin/rsvg-convert".into()),
    );
    assert!(
        p.exists(),
        "{} missing: bash scripts/setup-peers.sh (apt package librsvg2-bin) or set \
         RETROCOMP_RSVG_CONVERT",
        p.display()
    );
    p
}

/// An RGBA image.
pub(crate) struct Rgba {
    pub(crate) w: usize,
    pub(crate) h: usize,
    pub(crate) px: Vec<u8>,
}

impl Rgba {
    fn at(&self, x: usize, y: usize) -> (u8, u8, u8, u8) {
        let i = 4 * (y * self.w + x);
        (self.px[i], self.px[i + 1], self.px[i + 2], self.px[i + 3])
    }

    /// Pixels of `b` (shrunk by `inset` px, less `holes` grown by `inset`) whose colour is within
    /// `tol` (sum of |Δ|) of one of `colours`.
    pub(crate) fn count(
        &self,
        b: BoxPx,
        inset: f64,
        holes: &[BoxPx],
        colours: &[(u8, u8, u8)],
    ) -> usize {
        let (x0, y0) = (
            (b[0] + inset).max(0.0) as usize,
            (b[1] + inset).max(0.0) as usize,
        );
        let x1 = ((b[2] - inset).max(0.0) as usize).min(self.w);
        let y1 = ((b[3] - inset).max(0.0) as usize).min(self.h);
        let in_hole = |x: f64, y: f64| {
            holes.iter().any(|h| {
                x >= h[0] - inset && x <= h[2] + inset && y >= h[1] - inset && y <= h[3] + inset
            })
        };
        let mut n = 0;
        for y in y0..y1 {
            for x in x0..x1 {
                if in_hole(x as f64 + 0.5, y as f64 + 0.5) {
                    continue;
                }
                let (r, g, b, a) = self.at(x, y);
                if a > 200
                    && colours.iter().any(|c| {
                        u32::from(c.0.abs_diff(r))
                            + u32::from(c.1.abs_diff(g))
                            + u32::from(c.2.abs_diff(b))
                            <= 40
                    })
                {
                    n += 1;
                }
            }
        }
        n
    }
}

/// Renders `svg` to PNG with rsvg-convert and decodes it.
pub(crate) fn render(svg: &Path) -> Rgba {
    let png = svg.with_extension("png");
    let out = Command::new(rsvg_convert())
        .arg("--background-color=white")
        .arg("-o")
        .arg(&png)
        .arg(svg)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "rsvg-convert {}: {}",
        svg.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let dec = png::Decoder::new(std::fs::File::open(&png).unwrap());
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    let (w, h) = (info.width as usize, info.height as usize);
    let px = match info.color_type {
        png::ColorType::Rgba => buf[..4 * w * h].to_vec(),
        png::ColorType::Rgb => buf[..3 * w * h]
            .chunks(3)
            .flat_map(|c| [c[0], c[1], c[2], 255])
            .collect(),
        other => panic!("{}: unexpected PNG colour type {other:?}", png.display()),
    };
    Rgba { w, h, px }
}

/// Chromatic data colours (grey ones are left to the geometric check).
fn chromatic(g: &SvgGeometry) -> Vec<(u8, u8, u8)> {
    g.data_colours
        .iter()
        .copied()
        .filter(|c| !(c.0 == c.1 && c.1 == c.2))
        .collect()
}

/// Series-coloured pixels in the legend boxes of the rendering of `svg` (swatches excluded).
pub(crate) fn legend_pixels_of_data_colour(svg: &Path) -> (usize, SvgGeometry, Rgba) {
    let g = chart_geometry::parse(&std::fs::read_to_string(svg).unwrap());
    let img = render(svg);
    let colours = chromatic(&g);
    let n = g
        .legend_boxes
        .iter()
        .map(|b| img.count(*b, 2.0, &g.swatches, &colours))
        .sum();
    (n, g, img)
}

/// The figure at `svg` has a legend box with no data point in it (geometry) and no series-coloured
/// pixel in it (rendering), and its data are rendered (series-coloured pixels outside the box).
pub(crate) fn assert_legend_clear_in_pixels(svg: &Path, what: &str) {
    let (n, g, img) = legend_pixels_of_data_colour(svg);
    assert!(!g.legend_boxes.is_empty(), "{what}: a legend box");
    assert!(!g.data_points.is_empty(), "{what}: data drawn");
    assert!(
        g.covered().is_empty(),
        "{what}: legend covers {:?}",
        g.covered()
    );
    assert!(
        !g.swatches.is_empty(),
        "{what}: the legend has its swatches"
    );
    assert_eq!(n, 0, "{what}: {n} series-coloured pixels in the legend box");
    let colours = chromatic(&g);
    if !colours.is_empty() {
        let whole = [0.0, 0.0, img.w as f64, img.h as f64];
        let outside = img.count(whole, 0.0, &g.legend_boxes, &colours);
        assert!(outside > 50, "{what}: only {outside} data pixels rendered");
    }
}

/// The check sees an overlap: a marker of a series colour put in the middle of the legend box of
/// `svg` (a copy written next to it) shows up as series-coloured legend pixels.
pub(crate) fn assert_an_injected_overlap_is_seen(svg: &Path) {
    let text = std::fs::read_to_string(svg).unwrap();
    let g = chart_geometry::parse(&text);
    let b = g.legend_boxes[0];
    let c = chromatic(&g)[0];
    let (cx, cy) = ((b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0);
    let bad = text.replacen(
        "</svg>",
        &format!(
            "<circle cx=\"{cx}\" cy=\"{cy}\" r=\"4\" fill=\"#{:02X}{:02X}{:02X}\"/></svg>",
            c.0, c.1, c.2
        ),
        1,
    );
    let p = svg.with_file_name("injected-overlap.svg");
    std::fs::write(&p, bad).unwrap();
    let (n, g, _) = legend_pixels_of_data_colour(&p);
    assert!(!g.covered().is_empty(), "geometry sees the injected point");
    assert!(n > 10, "pixels see the injected point: {n}");
}
