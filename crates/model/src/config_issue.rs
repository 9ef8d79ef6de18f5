//! The one config-issue error of the workspace: every problem in a config file (machine model, field
//! config, bus config) is a [`ConfigIssue`] naming file, line (and column when known), the full key
//! path and what was expected; a [`ConfigError`] holds every issue found, in file order.
//!
//! Display: `file:line:column: key `k`: message`, with `:column` left out when unknown (0) and
//! `line` too when the problem has no place in the file (e.g. the file cannot be read).

use std::fmt;

/// One problem found in a config file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigIssue {
    pub file: String,
    /// 1-based; 0 when the problem has no place in the file (e.g. the file cannot be read).
    pub line: usize,
    /// 1-based; 0 when only the line is known.
    pub column: usize,
    /// Full key path, e.g. `components[2].forward_um[5]`.
    pub key: String,
    /// What is wrong and what was expected.
    pub message: String,
}

impl fmt::Display for ConfigIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.line, self.column) {
            (0, _) => write!(f, "{}: ", self.file)?,
            (l, 0) => write!(f, "{}:{l}: ", self.file)?,
            (l, c) => write!(f, "{}:{l}:{c}: ", self.file)?,
        }
        if !self.key.is_empty() {
            write!(f, "key `{}`: ", self.key)?;
        }
        write!(f, "{}", self.message)
    }
}

/// Why a config could not be loaded: every problem found, in file order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError {
    pub issues: Vec<ConfigIssue>,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, issue) in self.issues.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{issue}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigError {}

impl ConfigError {
    /// One issue without a column (`line` 0: no place in the file).
    pub fn single_at(file: &str, line: usize, key: &str, message: impl Into<String>) -> Self {
        ConfigError {
            issues: vec![ConfigIssue {
                file: file.into(),
                line,
                column: 0,
                key: key.into(),
                message: message.into(),
            }],
        }
    }

    /// One issue with no place in the file.
    pub fn single(file: &str, key: &str, message: impl Into<String>) -> Self {
        Self::single_at(file, 0, key, message)
    }

    /// A TOML syntax or schema error of `text`, placed at its span (or at the bracket it found
    /// unclosed, see `syntax_place`).
    pub fn from_toml(file: &str, text: &str, e: &toml::de::Error) -> Self {
        let msg = e.message().trim();
        let ((line, column), message) = match e.span() {
            None => ((0, 0), msg.to_string()),
            Some(s) => syntax_place(text, s.start, msg),
        };
        ConfigError {
            issues: vec![ConfigIssue {
                file: file.into(),
                line,
                column,
                key: String::new(),
                message,
            }],
        }
    }
}

/// Where a TOML syntax error at byte `at` belongs, and its message. The parser notices an array or
/// inline table left open only where the next key or table header starts (lines later); the
/// mistake is the bracket, so the error is placed on it, with the parser's own words kept.
pub(crate) fn syntax_place(text: &str, at: usize, msg: &str) -> ((usize, usize), String) {
    let here = line_col(text, at);
    let Some(open) = unclosed_bracket(text, at) else {
        return (here, msg.to_string());
    };
    let opened = line_col(text, open);
    let line_text = text.get(at..).unwrap_or("");
    let line_start = text[..at.min(text.len())].rfind('\n').map_or(0, |i| i + 1);
    let whole_line = text[line_start..].lines().next().unwrap_or("").trim_start();
    let starts_key_or_header = whole_line.starts_with('[')
        && whole_line[1..].starts_with(|c: char| c == '[' || c.is_ascii_alphabetic())
        || whole_line.split_once('=').is_some_and(|(k, _)| {
            !k.trim().is_empty()
                && k.trim()
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "_-.\"' ".contains(c))
        });
    if opened.0 < here.0 && (starts_key_or_header || line_text.trim().is_empty()) {
        let bracket = &text[open..=open];
        return (
            opened,
            format!(
                "`{bracket}` is not closed (the parser noticed at line {}: {msg})",
                here.0
            ),
        );
    }
    (here, msg.to_string())
}

/// Byte offset of the outermost `[` or `{` opened in a value (after `=`) before `byte` and not
/// closed by then; strings and comments are skipped.
fn unclosed_bracket(text: &str, byte: usize) -> Option<usize> {
    let b = text.as_bytes();
    let end = byte.min(b.len());
    let mut stack: Vec<usize> = Vec::new();
    let mut in_value = false;
    let mut i = 0;
    while i < end {
        match b[i] {
            b'#' => {
                while i < end && b[i] != b'\n' {
                    i += 1;
                }
                continue;
            }
            q @ (b'"' | b'\'') => {
                i += 1;
                while i < end && b[i] != q && b[i] != b'\n' {
                    if q == b'"' && b[i] == b'\\' {
                        i += 1;
                    }
                    i += 1;
                }
            }
            b'=' if stack.is_empty() => in_value = true,
            b'\n' if stack.is_empty() => in_value = false,
            b'[' | b'{' if in_value || !stack.is_empty() => stack.push(i),
            b']' | b'}' => {
                stack.pop();
            }
            _ => {}
        }
        i += 1;
    }
    stack.first().copied()
}

/// 1-based line and column (in characters) of byte offset `byte` of `text`.
pub(crate) fn line_col(text: &str, byte: usize) -> (usize, usize) {
    let before = &text.as_bytes()[..byte.min(text.len())];
    let line = before.iter().filter(|&&c| c == b'\n').count() + 1;
    let start = before
        .iter()
        .rposition(|&c| c == b'\n')
        .map_or(0, |i| i + 1);
    let column = String::from_utf8_lossy(&before[start..]).chars().count() + 1;
    (line, column)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_leaves_out_what_is_unknown() {
        let mut i = ConfigIssue {
            file: "f.toml".into(),
            line: 3,
            column: 7,
            key: "a.b".into(),
            message: "expected > 0".into(),
        };
        assert_eq!(i.to_string(), "f.toml:3:7: key `a.b`: expected > 0");
        i.column = 0;
        assert_eq!(i.to_string(), "f.toml:3: key `a.b`: expected > 0");
        i.line = 0;
        i.key.clear();
        assert_eq!(i.to_string(), "f.toml: expected > 0");
        assert_eq!(line_col("a = 1\nbé = x\n", 10), (2, 4));
    }

    #[test]
    fn a_toml_error_is_placed_at_its_span() {
        let text = "a = 1\nb = \"x\"\n";
        #[derive(Debug, serde::Deserialize)]
        #[allow(dead_code)]
        struct T {
            a: u32,
            b: u32,
        }
        let e = toml::from_str::<T>(text).unwrap_err();
        let c = ConfigError::from_toml("f.toml", text, &e);
        assert_eq!((c.issues[0].line, c.issues[0].column), (2, 5), "{c}");
        assert!(c.to_string().starts_with("f.toml:2:5: "), "{c}");
    }
}
