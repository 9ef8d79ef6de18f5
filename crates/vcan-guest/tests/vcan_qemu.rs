//! Real kernel vcan, from an ordinary `cargo test`: boots Debian's stock `linux-image-amd64` kernel in
//! a QEMU guest (TCG: no KVM needed, no SocketCAN needed on the host) with an initramfs holding the
//! can, can-raw, can-dev and vcan modules, can-utils and retrocomp's in-guest test program
//! (`crates/vcan-guest/src/main.rs`), and asserts the guest's result marker.
//!
//! Host peers: busybox-static, can-utils, cpio, and apt-get/dpkg for the first kernel and QEMU
//! download (cached in `~/.cache/retrocomp-vcan`, or `$RETROCOMP_VCAN_CACHE`). QEMU is the host's
//! `qemu-system-x86_64` if one is on PATH, else Debian's qemu-system-x86 unpacked into the cache by
//! `scripts/vcan-qemu/fetch-qemu.sh` (never installed: that could remove a newer host qemu-utils). If any is
//! missing the test FAILS saying how to install them: `scripts/setup-peers.sh`. On any guest failure
//! it prints the guest's whole serial console. See docs/vcan.md.

#![cfg(all(feature = "socketcan", target_os = "linux"))]

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Boot + tests take ~7 s under TCG on an idle host; a loaded 2-core CI box can be several times slower.
const QEMU_TIMEOUT: Duration = Duration::from_secs(180);
const MARKER: &str = "RETROCOMP-VCAN-RESULT: ";
const INSTALL_HINT: &str = "install the host peers with `sudo scripts/setup-peers.sh` \
     (apt-get install busybox-static can-utils cpio xz-utils; QEMU comes from \
     scripts/vcan-qemu/fetch-qemu.sh)";

fn repo() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

fn require_tool(name: &str) {
    let found = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).any(|d| d.join(name).is_file()))
        .unwrap_or(false);
    assert!(found, "`{name}` not found on PATH: {INSTALL_HINT}");
}

/// Runs a helper script; its last stdout line is the path it produced.
fn run_script(script: &str, args: &[&Path]) -> PathBuf {
    let path = repo().join("scripts/vcan-qemu").join(script);
    let out = Command::new("sh")
        .arg(&path)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", path.display()));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{script} failed ({}):\n{}\n{}\n{INSTALL_HINT}",
        out.status,
        stdout,
        String::from_utf8_lossy(&out.stderr)
    );
    let last = stdout.lines().last().unwrap_or("").trim().to_owned();
    assert!(!last.is_empty(), "{script} printed no path");
    PathBuf::from(last)
}

/// The check names the guest program will run (`vcan_guest --list`, run on the host), so the host
/// requires every one of them to report `ok` and a guest that silently runs fewer fails.
fn list_guest_checks(guest_bin: &Path) -> Vec<String> {
    let out = Command::new(guest_bin)
        .arg("--list")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {} --list: {e}", guest_bin.display()));
    assert!(
        out.status.success(),
        "{} --list: {}",
        guest_bin.display(),
        out.status
    );
    let names: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| l.trim().to_owned())
        .filter(|l| !l.is_empty())
        .collect();
    // The list covers both directions, extended/remote/error/FD frames and the error paths.
    assert!(names.len() >= 15, "guest lists only {names:?}");
    names
}

/// Boots the guest and returns (console text, wall time, whether it finished before the timeout).
fn boot(qemu: &Path, vmlinuz: &Path, initrd: &Path) -> (String, Duration, bool) {
    let start = Instant::now();
    let mut child = Command::new(qemu)
        .args(["-accel", "tcg", "-m", "512", "-smp", "1"])
        .args(["-nographic", "-no-reboot", "-nic", "none"])
        .arg("-kernel")
        .arg(vmlinuz)
        .arg("-initrd")
        .arg(initrd)
        .args(["-append", "console=ttyS0 quiet panic=-1"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}; {INSTALL_HINT}", qemu.display()));
    let mut stdout = child.stdout.take().unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let out_reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stdout.read_to_end(&mut buf);
        buf
    });
    let err_reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stderr.read_to_end(&mut buf);
        buf
    });
    let mut finished = true;
    loop {
        if child.try_wait().expect("wait for qemu").is_some() {
            break;
        }
        if start.elapsed() > QEMU_TIMEOUT {
            finished = false;
            let _ = child.kill();
            let _ = child.wait();
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let elapsed = start.elapsed();
    let mut console = String::from_utf8_lossy(&out_reader.join().unwrap()).into_owned();
    let err = err_reader.join().unwrap();
    if !err.is_empty() {
        console.push_str("\n--- qemu stderr ---\n");
        console.push_str(&String::from_utf8_lossy(&err));
    }
    (console, elapsed, finished)
}

#[test]
fn socketcan_backend_against_kernel_vcan_in_qemu() {
    for tool in ["busybox", "cansend", "candump", "cpio", "gzip"] {
        require_tool(tool);
    }
    let qemu = run_script("fetch-qemu.sh", &[]);
    let tree = run_script("fetch-kernel.sh", &[]);
    let vmlinuz = std::fs::read_dir(tree.join("boot"))
        .expect("kernel tree has boot/")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("vmlinuz-"))
        })
        .unwrap_or_else(|| panic!("no boot/vmlinuz-* in {}", tree.display()));
    let guest_bin = PathBuf::from(env!("CARGO_BIN_EXE_vcan_guest"));
    let guest_checks = list_guest_checks(&guest_bin);
    let initrd_path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("vcan-initramfs.cpio.gz");
    let initrd = run_script("build-initramfs.sh", &[&tree, &guest_bin, &initrd_path]);

    let (console, elapsed, finished) = boot(&qemu, &vmlinuz, &initrd);
    let result = console
        .lines()
        .find_map(|l| l.trim().strip_prefix(MARKER))
        .map(str::to_owned);
    let missing: Vec<&str> = guest_checks
        .iter()
        .map(String::as_str)
        .filter(|c| {
            !console
                .lines()
                .any(|l| l.trim() == format!("vcan-guest: ok {c}"))
        })
        .collect();
    let passed = finished && result.as_deref() == Some("PASS") && missing.is_empty();
    assert!(
        passed,
        "vcan QEMU guest FAILED: result marker {result:?}, finished before {QEMU_TIMEOUT:?}: \
             {finished}, checks not reported ok: {missing:?}, wall {elapsed:.1?}.\n\
             ===== guest console =====\n{console}\n===== end of guest console ====="
    );
    eprintln!(
        "vcan QEMU round trip passed in {elapsed:.1?} wall ({} checks)",
        guest_checks.len()
    );
}
