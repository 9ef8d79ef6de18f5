//! Supervision of `retrocomp run` for a service manager (systemd): a gateway that is half alive is
//! worse than one that restarts, so
//! - a panic in any task or thread ends the process with [`EXIT_TASK_PANICKED`] and one ERROR line
//!   ([`exit_on_panic`]); a source task that *returns* while the gateway runs is reported on
//!   [`SourceFeed::deaths`](crate::sources::SourceFeed::deaths) and the runtime stops with an error (exit status 1);
//! - the systemd watchdog (`Type=notify`, `WatchdogSec=`) is fed only while cycles progress: the
//!   cycle publishes its count on a [`CycleCounter`], a thread ([`spawn_watchdog`]) sends
//!   `READY=1` after the first cycle (sources opened, sink's initial read done, engine built) and
//!   `WATCHDOG=1` each half watchdog period in which the count advanced. A hung cycle stops the
//!   pings and systemd restarts the service (`WatchdogSignal`, then `Restart=`).
//!
//! The decision is the sans-IO [`WatchdogCore`]; the notification itself is the `sd-notify` crate
//! (a no-op when `NOTIFY_SOCKET` is unset, i.e. not under systemd).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::sync::mpsc;

/// Exit status after a panic (BSD `EX_SOFTWARE`): "internal software error".
pub const EXIT_TASK_PANICKED: i32 = 70;

/// Ping period when `NOTIFY_SOCKET` is set but no watchdog period was given (`Type=notify` only).
const DEFAULT_PING: Duration = Duration::from_secs(1);

/// Receives one line per supervised task that ended while it should still run.
#[derive(Debug)]
pub struct TaskDeaths(mpsc::UnboundedReceiver<String>);

/// Given to each supervised task: report why it ended.
#[derive(Clone, Debug)]
pub struct DeathNotice(mpsc::UnboundedSender<String>);

impl TaskDeaths {
    pub fn new() -> (DeathNotice, TaskDeaths) {
        let (tx, rx) = mpsc::unbounded_channel();
        (DeathNotice(tx), TaskDeaths(rx))
    }

    /// The next task that ended; pending forever when no task can report any more.
    pub async fn next(&mut self) -> String {
        match self.0.recv().await {
            Some(why) => why,
            None => std::future::pending().await,
        }
    }
}

impl DeathNotice {
    pub fn report(&self, task: &str, why: &str) {
        tracing::error!(
            task,
            why,
            "a gateway task ended; stopping so the service manager restarts it"
        );
        let _ = self.0.send(format!("task `{task}` ended: {why}"));
    }
}

/// The cycle's progress (cycles completed), readable from any thread.
#[derive(Clone, Debug, Default)]
pub struct CycleCounter(Arc<AtomicU64>);

impl CycleCounter {
    pub fn set(&self, cycles: u64) {
        self.0.store(cycles, Ordering::Relaxed);
    }
    pub fn get(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }
}

/// What to tell the service manager after one look at the cycle counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Notify {
    /// `READY=1`: the first cycle ran.
    Ready,
    /// `WATCHDOG=1`: cycles progressed since the last look.
    Alive,
}

/// Sans-IO watchdog decision: ping only when the cycle count advanced since the last look.
#[derive(Clone, Debug, Default)]
pub struct WatchdogCore {
    seen: u64,
    ready: bool,
}

impl WatchdogCore {
    pub fn look(&mut self, cycles: u64) -> Option<Notify> {
        if cycles <= self.seen {
            return None;
        }
        self.seen = cycles;
        if self.ready {
            Some(Notify::Alive)
        } else {
            self.ready = true;
            Some(Notify::Ready)
        }
    }
}

/// Start the watchdog thread when running under a service manager (`NOTIFY_SOCKET` set). It looks
/// at the counter every half `WATCHDOG_USEC` (or every second without one).
pub fn spawn_watchdog(
    cycles: CycleCounter,
) -> std::io::Result<Option<std::thread::JoinHandle<()>>> {
    if std::env::var_os("NOTIFY_SOCKET").is_none() {
        return Ok(None);
    }
    let period = sd_notify::watchdog_enabled().map_or(DEFAULT_PING, |d| d / 2);
    tracing::info!(
        ?period,
        "service manager notification on; watchdog look period"
    );
    std::thread::Builder::new()
        .name("sd-watchdog".into())
        .spawn(move || {
            let mut core = WatchdogCore::default();
            loop {
                std::thread::sleep(period);
                let state = match core.look(cycles.get()) {
                    Some(Notify::Ready) => sd_notify::NotifyState::Ready,
                    Some(Notify::Alive) => sd_notify::NotifyState::Watchdog,
                    None => continue,
                };
                if let Err(e) = sd_notify::notify(&[state]) {
                    tracing::warn!(%e, "cannot notify the service manager");
                }
            }
        })
        .map(Some)
}

/// Make every panic (any task, any thread) end the process with [`EXIT_TASK_PANICKED`] after the
/// standard panic message and one ERROR log line. For `retrocomp run` only: a library user keeps
/// Rust's default (a panicking tokio task is otherwise caught and the process lives on silently).
pub fn exit_on_panic() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        default(info);
        tracing::error!(
            panic = %info,
            status = EXIT_TASK_PANICKED,
            "a gateway task panicked; exiting so the service manager restarts the gateway"
        );
        std::process::exit(EXIT_TASK_PANICKED);
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ready_after_the_first_cycle_then_pings_only_on_progress() {
        let mut w = WatchdogCore::default();
        assert_eq!(w.look(0), None, "no cycle yet: not ready");
        assert_eq!(w.look(3), Some(Notify::Ready));
        assert_eq!(w.look(7), Some(Notify::Alive));
        assert_eq!(w.look(7), None, "a hung cycle gets no ping");
        assert_eq!(w.look(7), None);
        assert_eq!(w.look(8), Some(Notify::Alive));
    }

    #[tokio::test]
    async fn a_bare_sample_channel_reports_no_deaths() {
        let (_tx, rx) = mpsc::channel::<retrocomp_bus::Sample>(1);
        let mut feed = crate::sources::SourceFeed::from(rx);
        let next = tokio::time::timeout(Duration::from_millis(20), feed.deaths.next()).await;
        assert!(next.is_err(), "pending forever, never a spurious death");
        let (notice, mut deaths) = TaskDeaths::new();
        notice.report("can", "returned");
        assert!(deaths.next().await.contains("`can`"));
    }
}
