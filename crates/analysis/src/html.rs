//! One report per job as a single self-contained HTML file: inline CSS and inline SVG figures, no
//! script and no network, laid out for A4 printing (`@page`, figures never split across pages).
//! A header table (machine, axis, operator, date, environment, instrument, software version, input
//! files with their SHA-256) comes first, then sections of tables, figures and text.

use sha2::{Digest, Sha256};

/// One block of a section.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    Para(String),
    /// Preformatted text (a command's plain report).
    Pre(String),
    Table {
        head: Vec<String>,
        rows: Vec<Vec<String>>,
    },
    /// An SVG figure with its caption.
    Figure {
        svg: String,
        caption: String,
    },
    /// Bulleted list (e.g. what was assumed).
    List(Vec<String>),
}

#[derive(Debug, Clone, PartialEq)]
pub struct Section {
    pub heading: String,
    pub blocks: Vec<Block>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct HtmlReport {
    pub title: String,
    /// (field, value) rows of the header table.
    pub header: Vec<(String, String)>,
    pub sections: Vec<Section>,
}

/// Escapes text for HTML element content and attribute values.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            _ => o.push(c),
        }
    }
    o
}

/// Lower-case hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// `YYYY-MM-DD HH:MM UTC` of a Unix time in seconds (proleptic Gregorian, Hinnant's algorithm).
pub fn utc_datetime(unix_s: i64) -> String {
    let (days, secs) = (unix_s.div_euclid(86_400), unix_s.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02} UTC",
        secs / 3600,
        secs % 3600 / 60
    )
}

const CSS: &str = "@page{size:A4;margin:14mm 12mm}
body{font-family:'DejaVu Sans',Arial,sans-serif;font-size:10pt;color:#111;max-width:190mm;margin:auto}
h1{font-size:15pt;margin:0 0 4mm}h2{font-size:12pt;margin:6mm 0 2mm;border-bottom:1px solid #999}
table{border-collapse:collapse;margin:2mm 0}td,th{border:1px solid #bbb;padding:1px 5px;text-align:right}
th{background:#eee}table.header td{text-align:left}table.header td:first-child{font-weight:bold;width:32mm}
tr,figure{break-inside:avoid}figure{margin:3mm 0}figure svg{width:100%;height:auto}
figcaption{font-size:9pt;color:#333}pre{font-size:8pt;white-space:pre-wrap}
.hash{font-family:monospace;font-size:8pt;word-break:break-all}";

fn block_html(b: &Block, out: &mut String) {
    match b {
        Block::Para(t) => out.push_str(&format!("<p>{}</p>\n", escape(t))),
        Block::Pre(t) => out.push_str(&format!("<pre>{}</pre>\n", escape(t))),
        Block::List(items) => {
            out.push_str("<ul>\n");
            for i in items {
                out.push_str(&format!("<li>{}</li>\n", escape(i)));
            }
            out.push_str("</ul>\n");
        }
        Block::Table { head, rows } => {
            out.push_str("<table><thead><tr>");
            for h in head {
                out.push_str(&format!("<th>{}</th>", escape(h)));
            }
            out.push_str("</tr></thead><tbody>\n");
            for r in rows {
                out.push_str("<tr>");
                for c in r {
                    out.push_str(&format!("<td>{}</td>", escape(c)));
                }
                out.push_str("</tr>\n");
            }
            out.push_str("</tbody></table>\n");
        }
        Block::Figure { svg, caption } => {
            // The SVG is our own plotters output (no script); it is inlined as is.
            out.push_str("<figure>\n");
            out.push_str(svg.trim());
            out.push_str(&format!(
                "\n<figcaption>{}</figcaption></figure>\n",
                escape(caption)
            ));
        }
    }
}

/// The whole document.
pub fn render(r: &HtmlReport) -> String {
    let mut out = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>{}</title><style>{CSS}</style></head><body>\n<h1>{}</h1>\n<table class=\"header\">\n",
        escape(&r.title),
        escape(&r.title)
    );
    for (k, v) in &r.header {
        let class = if k.contains("SHA-256") {
            " class=\"hash\""
        } else {
            ""
        };
        out.push_str(&format!(
            "<tr><td>{}</td><td{class}>{}</td></tr>\n",
            escape(k),
            escape(v)
        ));
    }
    out.push_str("</table>\n");
    for s in &r.sections {
        out.push_str(&format!("<h2>{}</h2>\n", escape(&s.heading)));
        for b in &s.blocks {
            block_html(b, &mut out);
        }
    }
    out.push_str("</body></html>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_hashes_and_escaping() {
        assert_eq!(utc_datetime(0), "1970-01-01 00:00 UTC");
        assert_eq!(utc_datetime(951_827_696), "2000-02-29 12:34 UTC");
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let html = render(&HtmlReport {
            title: "a<b".into(),
            header: vec![("Machine".into(), "M&1".into())],
            sections: vec![Section {
                heading: "s".into(),
                blocks: vec![Block::Figure {
                    svg: "<svg viewBox=\"0 0 1 1\"></svg>".into(),
                    caption: "c".into(),
                }],
            }],
        });
        assert!(html.contains("<title>a&lt;b</title>") && html.contains("M&amp;1"));
        assert!(html.contains("<svg viewBox"));
        // Self-contained: nothing to fetch, nothing to run.
        assert!(!html.contains("<script") && !html.contains("src=") && !html.contains("href="));
    }
}
