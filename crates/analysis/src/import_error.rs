//! Located import errors: every importer in `analysis` reports the file, the 1-based line, the column
//! or key and what was expected, and collects *all* bad rows instead of stopping at (or skipping) one.

use std::fmt;

/// One problem in one input row.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportError {
    pub file: String,
    /// 1-based line number in the file (0 when the problem concerns the whole file).
    pub line: u64,
    /// Column name or key, when the problem is in one cell.
    pub column: Option<String>,
    pub message: String,
}

impl fmt::Display for ImportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.file, self.line)?;
        if let Some(c) = &self.column {
            write!(f, ": column `{c}`")?;
        }
        write!(f, ": {}", self.message)
    }
}

/// All problems found in one file. Returned as the error of every importer; never empty.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportErrors(pub Vec<ImportError>);

impl fmt::Display for ImportErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} problem(s) in input; nothing was imported:",
            self.0.len()
        )?;
        for e in &self.0 {
            writeln!(f, "  {e}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ImportErrors {}

/// Collects errors for one file; `finish` turns them into a `Result`.
#[derive(Debug)]
pub(crate) struct ErrorSink {
    file: String,
    errors: Vec<ImportError>,
}

impl ErrorSink {
    pub(crate) fn new(file: &str) -> Self {
        Self {
            file: file.to_string(),
            errors: Vec::new(),
        }
    }

    pub(crate) fn push(&mut self, line: u64, column: Option<&str>, message: impl Into<String>) {
        self.errors.push(ImportError {
            file: self.file.clone(),
            line,
            column: column.map(str::to_string),
            message: message.into(),
        });
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.errors.is_empty()
    }

    pub(crate) fn finish<T>(self, value: T) -> Result<T, ImportErrors> {
        if self.errors.is_empty() {
            Ok(value)
        } else {
            Err(ImportErrors(self.errors))
        }
    }

    /// Parses a finite float, recording a located error otherwise.
    pub(crate) fn parse_f64(&mut self, line: u64, column: &str, text: &str) -> Option<f64> {
        match text.trim().parse::<f64>() {
            Ok(v) if v.is_finite() => Some(v),
            Ok(_) => {
                self.push(
                    line,
                    Some(column),
                    format!("expected a finite number, found `{text}`"),
                );
                None
            }
            Err(_) => {
                self.push(
                    line,
                    Some(column),
                    format!("expected a number, found `{text}`"),
                );
                None
            }
        }
    }
}
