//! Reads back the geometry of an SVG that [`super::chart`] (or the polar plot) wrote, so tests can
//! check from the figure itself that no legend box covers data: the legend box is the `<rect>`
//! stroked [`super::chart::LEGEND_FRAME`]; data are `<circle>` centres and the vertices of
//! `<polyline>` and `<polygon>` elements (legend swatches are `<rect>`s, grid lines `<line>`s).
//! It also lists the legend's swatches and the colours the data were drawn in (black axes and
//! white excluded), so a test can look for those colours in a rendering of the legend box.

/// An axis-aligned box, px: `[left, top, right, bottom]`.
pub type BoxPx = [f64; 4];

/// What an SVG holds, px.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SvgGeometry {
    pub legend_boxes: Vec<BoxPx>,
    /// Circle centres and polyline/polygon vertices.
    pub data_points: Vec<(f64, f64)>,
    /// Filled `<rect>`s inside a legend box (one swatch per series).
    pub swatches: Vec<BoxPx>,
    /// Fill or stroke colours of the data elements (RGB), without black and white.
    pub data_colours: Vec<(u8, u8, u8)>,
}

impl SvgGeometry {
    /// Data points that fall inside any legend box.
    pub fn covered(&self) -> Vec<(f64, f64)> {
        self.data_points
            .iter()
            .copied()
            .filter(|(x, y)| {
                self.legend_boxes
                    .iter()
                    .any(|b| *x >= b[0] && *x <= b[2] && *y >= b[1] && *y <= b[3])
            })
            .collect()
    }
}

fn attr<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let at = tag.find(&key)? + key.len();
    let end = tag[at..].find('"')?;
    Some(&tag[at..at + end])
}

fn num(tag: &str, name: &str) -> Option<f64> {
    attr(tag, name)?.trim().parse().ok()
}

/// `#RRGGBB` → (r, g, b).
fn rgb(hex: &str) -> Option<(u8, u8, u8)> {
    let h = hex.strip_prefix('#').filter(|h| h.len() == 6)?;
    let c = |i: usize| u8::from_str_radix(&h[i..i + 2], 16).ok();
    Some((c(0)?, c(2)?, c(4)?))
}

fn rect_box(tag: &str) -> Option<BoxPx> {
    let (x, y) = (num(tag, "x")?, num(tag, "y")?);
    Some([x, y, x + num(tag, "width")?, y + num(tag, "height")?])
}

/// Parses the elements of `svg` that [`SvgGeometry`] needs; unknown elements are ignored.
pub fn parse(svg: &str) -> SvgGeometry {
    let frame = {
        let c = super::chart::LEGEND_FRAME;
        format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
    };
    let mut g = SvgGeometry::default();
    let mut filled_rects = vec![];
    let colour = |tag: &str, key: &str, g: &mut SvgGeometry| {
        if let Some(c) = attr(tag, key).and_then(rgb)
            && c != (0, 0, 0)
            && c != (255, 255, 255)
            && !g.data_colours.contains(&c)
        {
            g.data_colours.push(c);
        }
    };
    for piece in svg.split('<').skip(1) {
        let tag = piece.split('>').next().unwrap_or("");
        let name = tag.split_whitespace().next().unwrap_or("");
        match name {
            "rect" if attr(tag, "stroke").is_some_and(|s| s.eq_ignore_ascii_case(&frame)) => {
                g.legend_boxes.extend(rect_box(tag));
            }
            "rect" if attr(tag, "fill").is_some_and(|f| f != "none") => {
                filled_rects.extend(rect_box(tag));
            }
            "circle" => {
                if let (Some(x), Some(y)) = (num(tag, "cx"), num(tag, "cy")) {
                    g.data_points.push((x, y));
                }
                colour(tag, "fill", &mut g);
            }
            "polyline" | "polygon" => {
                for xy in attr(tag, "points").unwrap_or("").split_whitespace() {
                    let mut it = xy.split(',').map(|v| v.parse::<f64>());
                    if let (Some(Ok(x)), Some(Ok(y))) = (it.next(), it.next()) {
                        g.data_points.push((x, y));
                    }
                }
                colour(
                    tag,
                    if name == "polygon" { "fill" } else { "stroke" },
                    &mut g,
                );
            }
            _ => {}
        }
    }
    g.swatches = filled_rects
        .into_iter()
        .filter(|r| {
            g.legend_boxes
                .iter()
                .any(|b| r[0] >= b[0] && r[2] <= b[2] && r[1] >= b[1] && r[3] <= b[3])
        })
        .collect();
    g
}
