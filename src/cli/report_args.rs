//! The options every job's HTML report shares (`--html OUT` and the header fields), and the header
//! they make: what the input does not say is written as "not given", never guessed.

use std::path::{Path, PathBuf};

use anyhow::Context;
use retrocomp_analysis::html::{HtmlReport, Section, render, sha256_hex, utc_datetime};

use super::util::write;

#[derive(Debug, Clone, Default, clap::Args)]
pub(crate) struct ReportArgs {
    /// Write one self-contained HTML report (inline SVG and CSS, prints to A4): header, the
    /// standard's table, the figures and what was assumed (docs/reports.md).
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Report header: machine name.
    #[arg(long)]
    pub machine: Option<String>,
    /// Report header: axis or plane measured.
    #[arg(long = "report-axis")]
    pub report_axis: Option<String>,
    /// Report header: operator (left as a blank to sign when not given).
    #[arg(long)]
    pub operator: Option<String>,
    /// Report header: instrument (e.g. "XL-80 laser, XC-80 compensator").
    #[arg(long)]
    pub instrument: Option<String>,
    /// Report header: environment (e.g. "air 20.4 °C, machine 20.9 °C, 1012 hPa").
    #[arg(long)]
    pub environment: Option<String>,
}

const NOT_GIVEN: &str = "not given";

impl ReportArgs {
    /// The header rows: the fields above, date (UTC, now), software version and per input file its
    /// path and SHA-256.
    pub(crate) fn header(&self, inputs: &[&Path]) -> anyhow::Result<Vec<(String, String)>> {
        let or = |v: &Option<String>, d: &str| v.clone().unwrap_or_else(|| d.to_string());
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_secs()).unwrap_or(i64::MAX));
        let mut h = vec![
            ("Machine".to_string(), or(&self.machine, NOT_GIVEN)),
            ("Axis / plane".to_string(), or(&self.report_axis, NOT_GIVEN)),
            (
                "Operator".to_string(),
                or(&self.operator, "______________________ (signature)"),
            ),
            ("Date".to_string(), utc_datetime(now)),
            ("Environment".to_string(), or(&self.environment, NOT_GIVEN)),
            ("Instrument".to_string(), or(&self.instrument, NOT_GIVEN)),
            (
                "Software".to_string(),
                format!("retrocomp {}", env!("CARGO_PKG_VERSION")),
            ),
        ];
        for p in inputs {
            let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
            h.push((format!("Input {} SHA-256", p.display()), sha256_hex(&bytes)));
        }
        Ok(h)
    }

    /// Writes the report when `--html` was given.
    pub(crate) fn write(
        &self,
        title: &str,
        inputs: &[&Path],
        sections: impl FnOnce() -> anyhow::Result<Vec<Section>>,
    ) -> anyhow::Result<()> {
        let Some(out) = &self.html else {
            return Ok(());
        };
        let report = HtmlReport {
            title: title.to_string(),
            header: self.header(inputs)?,
            sections: sections()?,
        };
        write(out, &render(&report))
    }
}
