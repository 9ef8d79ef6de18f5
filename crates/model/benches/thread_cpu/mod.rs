//! Criterion's measurement by the benchmark thread's own CPU time (Linux
//! `CLOCK_THREAD_CPUTIME_ID`, nanosecond resolution), which stays meaningful when the machine is
//! shared and the thread is preempted (wall time then counts other processes' slices). Shared by
//! the model crate's `floor` bench and the root package's `models` bench (`#[path]`).

use criterion::measurement::{Measurement, ValueFormatter, WallTime};

/// CPU time of the calling thread, ns.
#[allow(
    missing_debug_implementations,
    reason = "criterion's WallTime has no Debug"
)]
pub(crate) struct ThreadCpuTime {
    wall: WallTime,
}

impl ThreadCpuTime {
    pub(crate) fn new() -> Self {
        Self { wall: WallTime }
    }
}

#[repr(C)]
struct Timespec {
    tv_sec: i64,
    tv_nsec: i64,
}

unsafe extern "C" {
    fn clock_gettime(clock_id: i32, tp: *mut Timespec) -> i32;
}

const CLOCK_THREAD_CPUTIME_ID: i32 = 3;

fn thread_cpu_ns() -> f64 {
    let mut ts = Timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is Linux's thread CPU clock.
    let rc = unsafe { clock_gettime(CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID) failed");
    #[allow(clippy::cast_precision_loss, reason = "ns of CPU time, < 2⁵³")]
    let ns = ts.tv_sec as f64 * 1e9 + ts.tv_nsec as f64;
    ns
}

impl Measurement for ThreadCpuTime {
    type Intermediate = f64;
    type Value = f64;
    fn start(&self) -> f64 {
        thread_cpu_ns()
    }
    fn end(&self, start: f64) -> f64 {
        thread_cpu_ns() - start
    }
    fn add(&self, a: &f64, b: &f64) -> f64 {
        a + b
    }
    fn zero(&self) -> f64 {
        0.0
    }
    fn to_f64(&self, v: &f64) -> f64 {
        *v
    }
    fn formatter(&self) -> &dyn ValueFormatter {
        // Values are nanoseconds, like the wall clock's: reuse its formatting.
        self.wall.formatter()
    }
}
