//! A small typed reader over toml's spanned document tree, so that every problem in a model file is
//! reported with file, line, column, the full key path and what was expected — and so that one run
//! reports all problems it can find instead of stopping at the first.

use std::cell::RefCell;

use toml::Spanned;
use toml::de::{DeArray, DeTable, DeValue};

pub(crate) use crate::config_issue::{ConfigError, ConfigIssue};

/// Collects issues while reading one file.
#[derive(Debug)]
pub(crate) struct Ctx<'t> {
    file: String,
    text: &'t str,
    issues: RefCell<Vec<ConfigIssue>>,
}

impl<'t> Ctx<'t> {
    pub(crate) fn new(file: &str, text: &'t str) -> Self {
        Ctx {
            file: file.to_string(),
            text,
            issues: RefCell::new(Vec::new()),
        }
    }

    fn line_col(&self, offset: usize) -> (usize, usize) {
        let before = &self.text[..offset.min(self.text.len())];
        let line = before.matches('\n').count() + 1;
        let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        (line, col)
    }

    pub(crate) fn err(&self, span: std::ops::Range<usize>, key: &str, message: impl Into<String>) {
        let (line, column) = self.line_col(span.start);
        self.issues.borrow_mut().push(ConfigIssue {
            file: self.file.clone(),
            line,
            column,
            key: key.to_string(),
            message: message.into(),
        });
    }

    pub(crate) fn has_errors(&self) -> bool {
        !self.issues.borrow().is_empty()
    }

    pub(crate) fn into_error(self) -> ConfigError {
        let mut issues = self.issues.into_inner();
        issues.sort_by_key(|i| (i.line, i.column));
        ConfigError { issues }
    }

    /// Parse the document; a syntax error becomes an issue with toml's own message.
    pub(crate) fn parse(&self) -> Option<Spanned<DeTable<'t>>> {
        match DeTable::parse(self.text) {
            Ok(t) => Some(t),
            Err(e) => {
                let at = e.span().map_or(0, |s| s.start);
                let ((line, column), msg) =
                    crate::config_issue::syntax_place(self.text, at, e.message().trim());
                self.issues.borrow_mut().push(ConfigIssue {
                    file: self.file.clone(),
                    line,
                    column,
                    key: String::new(),
                    message: format!("TOML syntax error: {msg}"),
                });
                None
            }
        }
    }
}

pub(crate) type Val<'t> = Spanned<DeValue<'t>>;

/// A table being read. Keys that are never asked for are reported by [`Tbl::finish`].
#[derive(Debug)]
pub(crate) struct Tbl<'a, 't> {
    pub ctx: &'a Ctx<'t>,
    pub table: &'a DeTable<'t>,
    pub path: String,
    pub span: std::ops::Range<usize>,
    used: RefCell<Vec<String>>,
}

fn type_name(v: &DeValue<'_>) -> &'static str {
    v.type_str()
}

fn as_f64(v: &DeValue<'_>) -> Option<f64> {
    match v {
        DeValue::Float(f) => f.as_str().replace('_', "").parse::<f64>().ok(),
        DeValue::Integer(i) => i64::from_str_radix(&i.as_str().replace('_', ""), i.radix())
            .ok()
            .map(|x| x as f64),
        _ => None,
    }
}

impl<'a, 't> Tbl<'a, 't> {
    pub(crate) fn new(
        ctx: &'a Ctx<'t>,
        table: &'a DeTable<'t>,
        path: String,
        span: std::ops::Range<usize>,
    ) -> Self {
        Tbl {
            ctx,
            table,
            path,
            span,
            used: RefCell::new(Vec::new()),
        }
    }

    pub(crate) fn key_path(&self, key: &str) -> String {
        if self.path.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.path)
        }
    }

    pub(crate) fn err_here(&self, message: impl Into<String>) {
        self.ctx.err(self.span.clone(), &self.path, message);
    }

    pub(crate) fn err_key(&self, key: &str, message: impl Into<String>) {
        let span = self.get_raw(key).map_or(self.span.clone(), |v| v.span());
        self.ctx.err(span, &self.key_path(key), message);
    }

    fn get_raw(&self, key: &str) -> Option<&'a Val<'t>> {
        self.table.get(key)
    }

    pub(crate) fn get(&self, key: &str) -> Option<&'a Val<'t>> {
        self.used.borrow_mut().push(key.to_string());
        self.get_raw(key)
    }

    pub(crate) fn has(&self, key: &str) -> bool {
        self.table.get(key).is_some()
    }

    /// All keys present, in file order of appearance is not guaranteed; used for suffix searches.
    pub(crate) fn keys(&self) -> Vec<String> {
        self.table
            .iter()
            .map(|(k, _)| k.get_ref().to_string())
            .collect()
    }

    /// Report keys that were never read, with the list of keys this table accepts. When this table
    /// already has a problem, keys that fit the accepted list were merely skipped after it and are
    /// not reported again.
    pub(crate) fn finish(&self, accepted: &str) {
        let used = self.used.borrow();
        let prefix = format!("{}.", self.path);
        let had_error = self
            .ctx
            .issues
            .borrow()
            .iter()
            .any(|i| i.key == self.path || i.key.starts_with(&prefix));
        let fits = |name: &str| {
            accepted.split(", ").any(|pat| match pat.find('<') {
                Some(i) => name.starts_with(&pat[..i]),
                None => name == pat.split_whitespace().next().unwrap_or(pat),
            })
        };
        for (k, v) in self.table.iter() {
            let name = k.get_ref().as_ref();
            let read = used.iter().any(|u| u == name);
            let skipped_after_error = had_error && fits(name);
            if !read && !skipped_after_error {
                self.ctx.err(
                    k.span().start..v.span().end,
                    &self.key_path(name),
                    format!("unknown key; expected one of: {accepted}"),
                );
            }
        }
    }

    pub(crate) fn str_opt(&self, key: &str) -> Option<String> {
        let v = self.get(key)?;
        match v.get_ref() {
            DeValue::String(s) => Some(s.to_string()),
            other => {
                self.ctx.err(
                    v.span(),
                    &self.key_path(key),
                    format!("expected a string, found {}", type_name(other)),
                );
                None
            }
        }
    }

    pub(crate) fn str_req(&self, key: &str, what: &str) -> Option<String> {
        if !self.has(key) {
            self.used.borrow_mut().push(key.to_string());
            self.err_here(format!("missing key `{key}` ({what})"));
            return None;
        }
        self.str_opt(key)
    }

    pub(crate) fn bool_opt(&self, key: &str) -> Option<bool> {
        let v = self.get(key)?;
        match v.get_ref() {
            DeValue::Boolean(b) => Some(*b),
            other => {
                self.ctx.err(
                    v.span(),
                    &self.key_path(key),
                    format!("expected true or false, found {}", type_name(other)),
                );
                None
            }
        }
    }

    pub(crate) fn int_opt(&self, key: &str) -> Option<i64> {
        let v = self.get(key)?;
        match v.get_ref() {
            DeValue::Integer(i) => {
                i64::from_str_radix(&i.as_str().replace('_', ""), i.radix()).ok()
            }
            other => {
                self.ctx.err(
                    v.span(),
                    &self.key_path(key),
                    format!("expected an integer, found {}", type_name(other)),
                );
                None
            }
        }
    }

    /// A finite number (integers are accepted).
    pub(crate) fn f64_opt(&self, key: &str) -> Option<f64> {
        let v = self.get(key)?;
        self.num_value(v, &self.key_path(key))
    }

    pub(crate) fn f64_req(&self, key: &str, what: &str) -> Option<f64> {
        if !self.has(key) {
            self.used.borrow_mut().push(key.to_string());
            self.err_here(format!("missing key `{key}` ({what})"));
            return None;
        }
        self.f64_opt(key)
    }

    fn num_value(&self, v: &Val<'t>, path: &str) -> Option<f64> {
        match as_f64(v.get_ref()) {
            Some(x) if x.is_finite() => Some(x),
            Some(x) => {
                self.ctx.err(
                    v.span(),
                    path,
                    format!("expected a finite number, found {x}"),
                );
                None
            }
            None => {
                self.ctx.err(
                    v.span(),
                    path,
                    format!("expected a number, found {}", type_name(v.get_ref())),
                );
                None
            }
        }
    }

    /// An array of finite numbers; every bad element is reported with its index.
    pub(crate) fn vec_opt(&self, key: &str) -> Option<Vec<f64>> {
        let v = self.get(key)?;
        self.vec_value(v, &self.key_path(key))
    }

    pub(crate) fn vec_value(&self, v: &Val<'t>, path: &str) -> Option<Vec<f64>> {
        let arr = self.array(v, path, "numbers")?;
        self.every_item(arr, path, |item, p| self.num_value(item, p))
    }

    /// The array in `v`, or `None` with "expected an array of {what}" reported at `path`.
    fn array<'v>(&self, v: &'v Val<'t>, path: &str, what: &str) -> Option<&'v DeArray<'t>> {
        match v.get_ref() {
            DeValue::Array(arr) => Some(arr),
            other => {
                self.ctx.err(
                    v.span(),
                    path,
                    format!("expected an array of {what}, found {}", type_name(other)),
                );
                None
            }
        }
    }

    /// `item` applied to every element (path `{path}[i]`); every bad element is reported by `item`,
    /// and the result is `None` if any was bad.
    fn every_item<T>(
        &self,
        arr: &DeArray<'t>,
        path: &str,
        item: impl Fn(&Val<'t>, &str) -> Option<T>,
    ) -> Option<Vec<T>> {
        let mut out = Vec::with_capacity(arr.len());
        let mut ok = true;
        for (i, v) in arr.iter().enumerate() {
            match item(v, &format!("{path}[{i}]")) {
                Some(x) => out.push(x),
                None => ok = false,
            }
        }
        ok.then_some(out)
    }

    /// An array of arrays of numbers (a matrix), rows may differ in length (checked by the caller).
    pub(crate) fn matrix_opt(&self, key: &str) -> Option<Vec<Vec<f64>>> {
        let v = self.get(key)?;
        let path = self.key_path(key);
        let arr = self.array(v, &path, "arrays")?;
        self.every_item(arr, &path, |row, p| self.vec_value(row, p))
    }

    pub(crate) fn vec3_opt(&self, key: &str) -> Option<[f64; 3]> {
        let v = self.get(key)?;
        let path = self.key_path(key);
        let xs = self.vec_value(v, &path)?;
        if xs.len() != 3 {
            self.ctx.err(
                v.span(),
                &path,
                format!("expected 3 numbers [x, y, z], found {}", xs.len()),
            );
            return None;
        }
        Some([xs[0], xs[1], xs[2]])
    }

    pub(crate) fn strings_opt(&self, key: &str) -> Option<Vec<String>> {
        let v = self.get(key)?;
        let path = self.key_path(key);
        let arr = self.array(v, &path, "strings")?;
        let mut out = Vec::new();
        for (i, item) in arr.iter().enumerate() {
            match item.get_ref() {
                DeValue::String(s) => out.push(s.to_string()),
                other => {
                    self.ctx.err(
                        item.span(),
                        &format!("{path}[{i}]"),
                        format!("expected a string, found {}", type_name(other)),
                    );
                    return None;
                }
            }
        }
        Some(out)
    }

    /// A sub-table (`[a.b]` or inline).
    pub(crate) fn table_opt(&self, key: &str) -> Option<Tbl<'a, 't>> {
        let v = self.get(key)?;
        match v.get_ref() {
            DeValue::Table(t) => Some(Tbl::new(self.ctx, t, self.key_path(key), v.span())),
            other => {
                self.ctx.err(
                    v.span(),
                    &self.key_path(key),
                    format!("expected a table, found {}", type_name(other)),
                );
                None
            }
        }
    }

    /// An array of tables (`[[key]]`); absent → empty.
    pub(crate) fn tables(&self, key: &str) -> Vec<Tbl<'a, 't>> {
        let Some(v) = self.get(key) else {
            return Vec::new();
        };
        let path = self.key_path(key);
        let Some(arr) = self.array(v, &path, &format!("tables `[[{key}]]`")) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (i, item) in arr.iter().enumerate() {
            match item.get_ref() {
                DeValue::Table(t) => {
                    out.push(Tbl::new(self.ctx, t, format!("{path}[{i}]"), item.span()));
                }
                other => self.ctx.err(
                    item.span(),
                    &format!("{path}[{i}]"),
                    format!("expected a table, found {}", type_name(other)),
                ),
            }
        }
        out
    }

    /// Find the one key `{prefix}_{unit}` present for one of `units`; reports a clash when two are
    /// present. Returns (unit, key).
    pub(crate) fn find_suffixed(&self, prefix: &str, units: &[&str]) -> Option<(String, String)> {
        let mut found: Vec<(String, String)> = Vec::new();
        for u in units {
            let k = format!("{prefix}_{u}");
            if self.has(&k) {
                found.push((u.to_string(), k));
            }
        }
        if found.len() > 1 {
            let names: Vec<&str> = found.iter().map(|f| f.1.as_str()).collect();
            self.err_key(
                &found[1].1,
                format!(
                    "give the value once, in one unit; found {}",
                    names.join(" and ")
                ),
            );
            for (_, k) in &found {
                self.used.borrow_mut().push(k.clone());
            }
            return None;
        }
        found.pop()
    }
}
