//! Reads back the geometry of an SVG that [`super::chart`] (or the polar plot) wrote, so tests can
//! check from the figure itself that no legend box covers data: the legend box is the `<rect>`
//! stroked [`super::chart::LEGEND_FRAME`]; data are `<circle>` centres and the vertices of
//! `<polyline>` and `<polygon>` elements (legend swatches are `<rect>`s, grid lines `<line>`s).

/// An axis-aligned box, px: `[left, top, right, bottom]`.
pub type BoxPx = [f64; 4];

/// What an SVG holds, px.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SvgGeometry {
    pub legend_boxes: Vec<BoxPx>,
    /// Circle centres and polyline/polygon vertices.
    pub data_points: Vec<(f64, f64)>,
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

/// Parses the elements of `svg` that [`SvgGeometry`] needs; unknown elements are ignored.
pub fn parse(svg: &str) -> SvgGeometry {
    let frame = {
        let c = super::chart::LEGEND_FRAME;
        format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)
    };
    let mut g = SvgGeometry::default();
    for piece in svg.split('<').skip(1) {
        let tag = piece.split('>').next().unwrap_or("");
        let name = tag.split_whitespace().next().unwrap_or("");
        match name {
            "rect" if attr(tag, "stroke").is_some_and(|s| s.eq_ignore_ascii_case(&frame)) => {
                if let (Some(x), Some(y), Some(w), Some(h)) = (
                    num(tag, "x"),
                    num(tag, "y"),
                    num(tag, "width"),
                    num(tag, "height"),
                ) {
                    g.legend_boxes.push([x, y, x + w, y + h]);
                }
            }
            "circle" => {
                if let (Some(x), Some(y)) = (num(tag, "cx"), num(tag, "cy")) {
                    g.data_points.push((x, y));
                }
            }
            "polyline" | "polygon" => {
                for xy in attr(tag, "points").unwrap_or("").split_whitespace() {
                    let mut it = xy.split(',').map(|v| v.parse::<f64>());
                    if let (Some(Ok(x)), Some(Ok(y))) = (it.next(), it.next()) {
                        g.data_points.push((x, y));
                    }
                }
            }
            _ => {}
        }
    }
    g
}
