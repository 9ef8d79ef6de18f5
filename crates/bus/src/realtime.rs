//! The gateway's real-time threads: the cycle and the sink each run on a dedicated OS thread (not a
//! tokio worker), so busy tokio tasks (status requests, source decoding, the in-process hubs of the
//! demo) never delay a cycle or a controller write. Optionally, per `[gateway]`:
//!
//! - `realtime_priority = N` (1–99): those threads ask for `SCHED_FIFO` priority N
//!   (`pthread_setschedparam`). Needs root, `CAP_SYS_NICE`, or an `RLIMIT_RTPRIO` ≥ N (the systemd
//!   unit sets `LimitRTPRIO`). Refused → one WARN line saying why and how to allow it; the gateway
//!   runs on under the normal scheduler (never a start failure: compensation under load is better
//!   than none).
//! - `lock_memory = true`: `mlockall(MCL_CURRENT | MCL_FUTURE)` at start, so a page fault never
//!   stalls a cycle (needs `CAP_IPC_LOCK` or `RLIMIT_MEMLOCK`; same WARN-and-continue policy).
//!
//! The sources' reader threads (`sources.rs`) get the same priority: they stamp each sample when
//! they read it, so a starved reader makes fresh data look stale (issue 18.5). The tokio workers
//! and the status endpoint stay under the normal scheduler; the kernel's real-time throttling
//! (`sched_rt_runtime_us`, 95 % by default) leaves the host a share even if a real-time thread spun.

use std::thread::JoinHandle;

/// What a real-time request got (also logged, once per thread).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RtOutcome {
    /// No priority asked for: normal scheduler.
    NotRequested,
    Granted {
        priority: u8,
    },
    /// The kernel refused (`errno` text) — the thread runs under the normal scheduler.
    Refused {
        priority: u8,
        why: String,
    },
}

/// Put the calling thread on `SCHED_FIFO` at `priority` (1–99), or say why not.
pub fn set_current_thread_fifo(priority: u8) -> RtOutcome {
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: pthread_self() is the calling thread; `param` is a valid sched_param for the call.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        RtOutcome::Granted { priority }
    } else {
        RtOutcome::Refused {
            priority,
            why: std::io::Error::from_raw_os_error(rc).to_string(),
        }
    }
}

/// Apply `priority` (if any) to the calling thread and log the outcome once.
pub fn apply_priority(thread: &str, priority: Option<u8>) -> RtOutcome {
    let Some(p) = priority else {
        return RtOutcome::NotRequested;
    };
    let got = set_current_thread_fifo(p);
    match &got {
        RtOutcome::Granted { priority } => {
            tracing::info!(thread, priority, "SCHED_FIFO granted");
        }
        RtOutcome::Refused { priority, why } => tracing::warn!(
            thread,
            priority,
            why,
            "gateway.realtime_priority: SCHED_FIFO refused; running under the normal scheduler \
             (run as root, with CAP_SYS_NICE, or with LimitRTPRIO={priority} in the systemd unit)"
        ),
        RtOutcome::NotRequested => {}
    }
    got
}

/// `mlockall(MCL_CURRENT | MCL_FUTURE)`; logs the outcome. Returns whether memory is locked.
pub fn lock_memory() -> bool {
    // SAFETY: mlockall takes flags only and touches no Rust-visible memory.
    let rc = unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) };
    if rc == 0 {
        tracing::info!("gateway.lock_memory: all pages locked in RAM (mlockall)");
        true
    } else {
        let why = std::io::Error::last_os_error().to_string();
        tracing::warn!(
            why,
            "gateway.lock_memory: mlockall refused; pages may be swapped or faulted in during a \
             cycle (run as root, with CAP_IPC_LOCK, or with LimitMEMLOCK=infinity in the systemd unit)"
        );
        false
    }
}

/// Spawn a named OS thread that first applies `priority`, then runs `f`.
pub fn spawn_thread<T: Send + 'static>(
    name: &str,
    priority: Option<u8>,
    f: impl FnOnce() -> T + Send + 'static,
) -> std::io::Result<JoinHandle<T>> {
    let thread = name.to_string();
    std::thread::Builder::new()
        .name(thread.clone())
        .spawn(move || {
            apply_priority(&thread, priority);
            f()
        })
}

/// Spawn a named OS thread with its own current-thread tokio runtime and run the future that
/// `make` builds there. Sockets opened inside belong to this thread's reactor, so their wake-ups
/// do not wait for a busy worker of the main runtime.
pub fn spawn_runtime_thread<F, T>(
    name: &str,
    priority: Option<u8>,
    make: impl FnOnce() -> F + Send + 'static,
) -> std::io::Result<JoinHandle<T>>
where
    F: Future<Output = T>,
    T: Send + 'static,
{
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    spawn_thread(name, priority, move || rt.block_on(make()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fifo_request_is_granted_or_refused_with_a_reason_and_the_thread_runs_either_way() {
        let h = spawn_thread("rt-test", Some(10), || {
            // Whatever the kernel said, the thread's work still runs.
            let mut policy = 0;
            let mut param = libc::sched_param { sched_priority: 0 };
            // SAFETY: valid out-pointers for the calling thread's policy and parameters.
            let rc = unsafe {
                libc::pthread_getschedparam(libc::pthread_self(), &mut policy, &mut param)
            };
            assert_eq!(rc, 0);
            (policy, param.sched_priority)
        })
        .unwrap();
        let (policy, prio) = h.join().unwrap();
        // Re-ask on a fresh thread to read the outcome itself.
        let got = spawn_thread("rt-test2", None, || set_current_thread_fifo(10))
            .unwrap()
            .join()
            .unwrap();
        match got {
            RtOutcome::Granted { priority } => {
                assert_eq!(priority, 10);
                assert_eq!((policy, prio), (libc::SCHED_FIFO, 10));
            }
            RtOutcome::Refused { why, .. } => {
                assert!(!why.is_empty());
                assert_eq!(
                    policy,
                    libc::SCHED_OTHER,
                    "refused must leave the normal policy"
                );
            }
            RtOutcome::NotRequested => panic!("a priority was requested"),
        }
        assert_eq!(apply_priority("none", None), RtOutcome::NotRequested);
    }

    #[test]
    fn a_runtime_thread_runs_its_future_on_its_own_runtime() {
        let h = spawn_runtime_thread("rt-rt", None, || async {
            tokio::time::sleep(std::time::Duration::from_millis(1)).await;
            std::thread::current().name().map(str::to_string)
        })
        .unwrap();
        assert_eq!(h.join().unwrap().as_deref(), Some("rt-rt"));
    }
}
