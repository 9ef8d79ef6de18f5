//! Which stage a diagnosis is in (the signal, its noise pre-pass, a selection step's screening,
//! the exchange, the final refit), for a caller's progress line (`retrocomp diagnose` draws it on
//! stderr). One observer per process, set with [`observe`] and removed when its guard drops; with
//! none set a stage costs one uncontended read lock. Stages are reported from the thread that
//! drives a signal's diagnosis, never from the parallel screening, so the observer sees each
//! signal's stages in order (two signals diagnosed side by side interleave theirs).

use std::sync::RwLock;

type Observer = Box<dyn Fn(&str) + Send + Sync>;

static OBSERVER: RwLock<Option<Observer>> = RwLock::new(None);

/// Removes the observer set by [`observe`] when dropped.
#[must_use = "the observer is removed when the guard drops"]
#[derive(Debug)]
pub struct Observing(());

impl Drop for Observing {
    fn drop(&mut self) {
        if let Ok(mut o) = OBSERVER.write() {
            *o = None;
        }
    }
}

/// Call `f` with each stage's name until the returned guard drops.
pub fn observe(f: impl Fn(&str) + Send + Sync + 'static) -> Observing {
    if let Ok(mut o) = OBSERVER.write() {
        *o = Some(Box::new(f));
    }
    Observing(())
}

/// Report a stage; `what` is only formatted when someone observes.
pub(crate) fn stage(what: impl FnOnce() -> String) {
    if let Ok(o) = OBSERVER.read()
        && let Some(f) = o.as_ref()
    {
        f(&what());
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    #[test]
    fn an_observer_sees_stages_until_its_guard_drops() {
        let seen = Arc::new(Mutex::new(vec![]));
        let s = Arc::clone(&seen);
        let guard = super::observe(move |w| s.lock().unwrap().push(w.to_string()));
        super::stage(|| "ex: screening".into());
        drop(guard);
        super::stage(|| "ey: screening".into());
        assert_eq!(*seen.lock().unwrap(), vec!["ex: screening".to_string()]);
    }
}
