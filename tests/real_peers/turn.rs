//! Whose turn it is: the files of this binary were each a test binary of their own, and cargo ran
//! test binaries one after another. Their tests hold real sockets, child processes (LinuxCNC,
//! Mosquitto, Chromium, python peers) and wall-clock timing, so tests of two files must not
//! overlap here either: a test takes its file's turn first. Tests of the same file may overlap,
//! as they did in their own binary (libtest runs two at a time on two cores).

use std::sync::{Condvar, Mutex, PoisonError};

/// The file whose tests run now, and how many of them.
static NOW: Mutex<(Option<&'static str>, usize)> = Mutex::new((None, 0));
static FREED: Condvar = Condvar::new();

/// Held for the duration of a test; dropping it (also on a panic) lets other files' tests run.
#[derive(Debug)]
pub(crate) struct Turn;

/// Wait until no test of another file runs, then run; `file` is the caller's `file!()`.
pub(crate) fn take(file: &'static str) -> Turn {
    let mut now = NOW.lock().unwrap_or_else(PoisonError::into_inner);
    while now.0.is_some_and(|f| f != file) {
        now = FREED.wait(now).unwrap_or_else(PoisonError::into_inner);
    }
    now.0 = Some(file);
    now.1 += 1;
    Turn
}

impl Drop for Turn {
    fn drop(&mut self) {
        let mut now = NOW.lock().unwrap_or_else(PoisonError::into_inner);
        now.1 -= 1;
        if now.1 == 0 {
            now.0 = None;
            FREED.notify_all();
        }
    }
}

#[test]
fn a_second_file_waits_for_the_first_files_tests_and_the_same_file_does_not() {
    use std::sync::mpsc;
    use std::time::Duration;
    // Its own keys ("turn-test a", "turn-test b"): it waits, like any file, until no other file's
    // test holds the turn, and holds up the other files while it runs.
    let first = take("turn-test a");
    let same = take("turn-test a");
    let (tx, rx) = mpsc::channel();
    let waiter = std::thread::spawn(move || {
        let t = take("turn-test b");
        tx.send(()).unwrap();
        drop(t);
    });
    // Not a timing assertion on this machine's speed: b cannot get its turn while a holds it,
    // however long we wait; 200 ms only bounds how long we look.
    assert!(
        rx.recv_timeout(Duration::from_millis(200)).is_err(),
        "b ran while a held the turn"
    );
    drop(first);
    assert!(
        rx.recv_timeout(Duration::from_millis(200)).is_err(),
        "b ran while a still ran one test"
    );
    drop(same);
    rx.recv().expect("b runs once a's tests are done");
    waiter.join().unwrap();
}
