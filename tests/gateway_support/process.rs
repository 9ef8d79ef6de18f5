//! Stopping the gateway binary the way systemd does, shared by the binary-level gateway tests.

use std::process::{Child, Command};
use std::time::Duration;

/// Send SIGTERM, wait up to 5 s for a clean exit (killing it and failing otherwise), assert the exit
/// status is success, and return what the gateway wrote to stderr.
pub(crate) fn stop_with_sigterm(child: &mut Child) -> String {
    Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    let mut code = None;
    for _ in 0..100 {
        if let Some(s) = child.try_wait().unwrap() {
            code = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let code = code.unwrap_or_else(|| {
        let _ = child.kill();
        panic!("gateway did not stop on SIGTERM")
    });
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert!(code.success(), "exit {code:?}: {err}");
    err
}
