//! LinuxCNC's programs as uid 65534 (`rtapi_app` refuses root), one LinuxCNC at a time on this
//! host (flock on /tmp/retrocomp-linuxcnc.lock: two HAL instances share one shared-memory key).

use std::path::Path;
use std::process::Command;

/// `flock … setpriv --reuid=65534 … env HOME=<home>`: append the program and its arguments.
pub(crate) fn one_at_a_time_as_nobody(home: &Path) -> Command {
    let mut c = Command::new("flock");
    c.args(["-w", "1200", "/tmp/retrocomp-linuxcnc.lock"])
        .args([
            "setpriv",
            "--reuid=65534",
            "--regid=65534",
            "--clear-groups",
        ])
        .arg("env")
        .arg(format!("HOME={}", home.display()));
    c
}
