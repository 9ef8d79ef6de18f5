//! Deadlines of the sans-IO sources (CANopen, serial lines): when a source's `poll` next has
//! something to report, and how long its shell sleeps until then. Times are seconds on the
//! caller's clock, as everywhere in the sources; a deadline in the past means "poll now".

use std::time::Duration;

/// The longest a shell sleeps with no deadline at all (it wakes on input anyway).
const IDLE: Duration = Duration::from_secs(3600);

/// When `poll` next reports one channel: at `stale_from_s`, the moment the channel turns stale,
/// unless the last poll (`last_poll_s`) came at or after it: then the channel was reported (or
/// was fresh at that instant after all) and is reported again `repeat_s` after that poll.
/// Never earlier than the last poll, so a shell that polls at a deadline always moves on.
pub(crate) fn stale_report_due_s(
    stale_from_s: f64,
    last_poll_s: Option<f64>,
    repeat_s: f64,
) -> f64 {
    match last_poll_s {
        Some(p) if p >= stale_from_s => p + repeat_s,
        _ => stale_from_s,
    }
}

/// How long a shell sleeps at `now_s` until `due_s` (zero if it has passed; [`IDLE`] without one).
pub(crate) fn sleep_for(due_s: Option<f64>, now_s: f64) -> Duration {
    due_s.map_or(IDLE, |d| {
        let s = d - now_s;
        if s > 0.0 {
            Duration::try_from_secs_f64(s).map_or(IDLE, |d| d.min(IDLE))
        } else {
            Duration::ZERO
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stale_channel_is_due_when_it_turns_stale_then_every_repeat() {
        assert_eq!(stale_report_due_s(1.5, None, 0.01), 1.5, "never polled");
        assert_eq!(
            stale_report_due_s(1.5, Some(1.0), 0.01),
            1.5,
            "fresh at the last poll"
        );
        assert_eq!(
            stale_report_due_s(1.5, Some(1.5), 0.01),
            1.51,
            "polled at the instant"
        );
        assert_eq!(
            stale_report_due_s(f64::NEG_INFINITY, None, 0.25),
            f64::NEG_INFINITY
        );
        assert_eq!(stale_report_due_s(f64::NEG_INFINITY, Some(2.0), 0.25), 2.25);
    }

    #[test]
    fn a_shell_sleeps_until_the_deadline_and_never_negative() {
        assert_eq!(sleep_for(Some(2.5), 2.0), Duration::from_millis(500));
        assert_eq!(sleep_for(Some(1.0), 2.0), Duration::ZERO);
        assert_eq!(sleep_for(Some(f64::NEG_INFINITY), 2.0), Duration::ZERO);
        assert_eq!(sleep_for(Some(f64::INFINITY), 2.0), IDLE);
        assert_eq!(sleep_for(None, 2.0), IDLE);
    }
}
