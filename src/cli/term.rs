//! The command line's terminal manners, one place for every subcommand:
//! - [`Progress`]: what a long job is doing, on stderr (indicatif), drawn only when stderr is a
//!   terminal (a pipe, a file or the journal get nothing), cleared when the job's output follows;
//! - [`colour`]: ANSI colour only on a terminal and never with `NO_COLOR` (no-color.org);
//! - [`init_tracing`]: the log subscriber on stderr, without colour off a terminal and, under
//!   systemd with stderr to the journal (`JOURNAL_STREAM`), without its own timestamp (journald
//!   stamps every line) or colour.

use std::borrow::Cow;
use std::io::IsTerminal as _;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A job's progress on stderr: a spinner with the stage and the elapsed time, or a bar when the
/// amount of work is known. Hidden when stderr is not a terminal; cleared on drop.
pub(crate) struct Progress(ProgressBar);

impl Progress {
    /// A job of unknown length: `what` it is doing, then the elapsed time.
    pub(crate) fn spinner(what: impl Into<Cow<'static, str>>) -> Progress {
        let pb = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
        pb.set_style(
            ProgressStyle::with_template("{spinner} {msg} ({elapsed})").expect("a fixed template"),
        );
        pb.set_message(what);
        pb.enable_steady_tick(Duration::from_millis(120));
        Progress(pb)
    }

    /// A job of `len` units (bytes, rows, cases): a bar with the count and the time left.
    pub(crate) fn bar(len: u64, what: impl Into<Cow<'static, str>>) -> Progress {
        let pb = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
        pb.set_style(
            ProgressStyle::with_template(
                "{msg} [{bar:30}] {percent:>3}% {human_pos}/{human_len} ({elapsed}, ~{eta} left)",
            )
            .expect("a fixed template")
            .progress_chars("=> "),
        );
        pb.set_message(what);
        pb.enable_steady_tick(Duration::from_millis(250));
        Progress(pb)
    }

    /// A job counting `what` (rows, records) of unknown total: the count, the rate, the time.
    pub(crate) fn counter(what: impl Into<Cow<'static, str>>) -> Progress {
        let pb = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
        pb.set_style(
            ProgressStyle::with_template("{spinner} {msg}: {human_pos} ({per_sec}, {elapsed})")
                .expect("a fixed template"),
        );
        pb.set_message(what);
        pb.enable_steady_tick(Duration::from_millis(250));
        Progress(pb)
    }

    /// The job moved on to another stage.
    pub(crate) fn stage(&self, what: impl Into<Cow<'static, str>>) {
        self.0.set_message(what);
    }

    /// A handle that sets the stage from another place (a library's stage observer: it must be
    /// `Send + Sync`, which the bar's handle is).
    pub(crate) fn stage_setter(&self) -> impl Fn(&str) + Send + Sync + 'static {
        let pb = self.0.clone();
        move |what: &str| pb.set_message(what.to_string())
    }

    /// `n` more units of a [`Progress::bar`] done.
    pub(crate) fn inc(&self, n: u64) {
        self.0.inc(n);
    }

    /// Run `f` (which prints to the terminal) with the progress line out of its way.
    pub(crate) fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        self.0.suspend(f)
    }

    /// Done: the line is cleared (the job's own output follows).
    pub(crate) fn finish(self) {}
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.0.finish_and_clear();
    }
}

/// ANSI colour on stderr: only on a terminal, never with a non-empty `NO_COLOR`, never into the
/// journal.
pub(crate) fn colour() -> bool {
    colour_when(
        std::io::stderr().is_terminal(),
        std::env::var_os("NO_COLOR").as_deref(),
        stderr_is_journal(),
    )
}

fn colour_when(terminal: bool, no_color: Option<&std::ffi::OsStr>, journal: bool) -> bool {
    terminal && no_color.is_none_or(|v| v.is_empty()) && !journal
}

/// systemd connected stderr to the journal: `JOURNAL_STREAM` is `<device>:<inode>` of that
/// stream, and it is stderr's (a child whose stderr was redirected inherits the variable but not
/// the stream).
fn stderr_is_journal() -> bool {
    use std::os::fd::AsFd as _;
    let Some(v) = std::env::var_os("JOURNAL_STREAM") else {
        return false;
    };
    let Ok(fd) = std::io::stderr().as_fd().try_clone_to_owned() else {
        return false;
    };
    std::fs::File::from(fd)
        .metadata()
        .is_ok_and(|m| names_stream(&v, &m))
}

/// `JOURNAL_STREAM`'s `<device>:<inode>` is the stream of `m`.
fn names_stream(journal_stream: &std::ffi::OsStr, m: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt as _;
    journal_stream
        .to_str()
        .and_then(|s| s.split_once(':'))
        .is_some_and(|(dev, ino)| dev.parse() == Ok(m.dev()) && ino.parse() == Ok(m.ino()))
}

/// The tracing subscriber on stderr: `RUST_LOG`, else `default_filter`; colour per [`colour`];
/// under journald no timestamp (journald adds its own).
pub(crate) fn init_tracing(default_filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    let fmt = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(colour());
    // async-opcua's missing-certificate ERRORs are false for an anonymous-only server.
    let quiet = tracing_subscriber::filter::filter_fn(|m| {
        !retrocomp_gateway::northbound::opcua::is_false_certificate_report(m)
    });
    let _ = if stderr_is_journal() {
        fmt.without_time().finish().with(quiet).try_init()
    } else {
        fmt.finish().with(quiet).try_init()
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_only_on_a_terminal_without_no_color_and_not_into_the_journal() {
        let set = Some(std::ffi::OsStr::new("1"));
        assert!(colour_when(true, None, false));
        assert!(
            colour_when(true, Some(std::ffi::OsStr::new("")), false),
            "empty = unset"
        );
        assert!(!colour_when(true, set, false));
        assert!(!colour_when(false, None, false));
        assert!(!colour_when(true, None, true));
    }

    #[test]
    fn journal_stream_names_a_stream_by_device_and_inode() {
        use std::os::unix::fs::MetadataExt as _;
        let f = tempfile::tempfile().unwrap();
        let m = f.metadata().unwrap();
        let v = format!("{}:{}", m.dev(), m.ino());
        assert!(names_stream(std::ffi::OsStr::new(&v), &m));
        let other = format!("{}:{}", m.dev(), m.ino() + 1);
        assert!(!names_stream(std::ffi::OsStr::new(&other), &m));
        assert!(!names_stream(std::ffi::OsStr::new("garbage"), &m));
    }
}
