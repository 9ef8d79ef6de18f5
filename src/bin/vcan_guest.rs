//! The in-guest half of the real-kernel vcan test: runs INSIDE the QEMU guest that
//! `tests/vcan_qemu.rs` boots (scripts/vcan-qemu/init brings vcan0 up first), never on the host.
//!
//! It checks retrocomp's `SocketCanBus` against the kernel's vcan0 with can-utils as the independent
//! peer, in both directions: `cansend` → `SocketCanBus::recv`, and `SocketCanBus::send` → `candump`.
//! Each check prints `vcan-guest: ok <name>` or `vcan-guest: FAIL <name>: <why>`; the host test
//! requires every name in [`CHECKS`]. Exit status 0 iff all passed.
//!
//! CiA 406 fixture: TPDO1 of node 1 has COB-ID 0x180 + 1 and maps 6004h (position, U32,
//! little-endian, CiA 301 byte order), so `181#78563412` carries 0x1234_5678 counts.

#[cfg(all(feature = "socketcan", target_os = "linux"))]
mod guest {
    use anyhow::{Context, Result, bail, ensure};
    use embedded_can::{Frame as _, Id, StandardId};
    use retrocomp::bus::can::socketcan::SocketCanBus;
    use retrocomp::bus::can::{CanBus, CanError, Frame};
    use std::time::Duration;
    use tokio::io::AsyncReadExt;
    use tokio::process::Command;
    use tokio::time::timeout;

    const IF: &str = "vcan0";
    /// Generous: TCG emulation is 10–50× slower than the host.
    const STEP_TIMEOUT: Duration = Duration::from_secs(10);

    /// Every check the host test expects to see passed, in run order.
    pub const CHECKS: &[&str] = &[
        "open_missing_interface_is_not_found",
        "open_non_can_interface_is_not_found",
        "cansend_cia406_tpdo_to_retrocomp",
        "cansend_extended_to_retrocomp",
        "cansend_remote_to_retrocomp",
        "cansend_empty_to_retrocomp",
        "cansend_error_frame_is_counted_and_skipped",
        "retrocomp_to_candump",
        "retrocomp_burst_in_order",
    ];

    pub async fn run() -> bool {
        let mut failed = 0usize;
        for &name in CHECKS {
            let result = match name {
                "open_missing_interface_is_not_found" => open_not_found("rcnone0"),
                "open_non_can_interface_is_not_found" => open_not_found("lo"),
                "cansend_cia406_tpdo_to_retrocomp" => cansend_cia406_tpdo().await,
                "cansend_extended_to_retrocomp" => {
                    let want = Frame::extended(0x18FF_50E5, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
                    cansend_expect("18FF50E5#0102030405060708", want).await
                }
                "cansend_remote_to_retrocomp" => cansend_remote().await,
                "cansend_empty_to_retrocomp" => {
                    cansend_expect("7FF#", Frame::standard(0x7FF, &[]).unwrap()).await
                }
                "cansend_error_frame_is_counted_and_skipped" => error_frame_skipped().await,
                "retrocomp_to_candump" => retrocomp_to_candump().await,
                "retrocomp_burst_in_order" => burst_in_order().await,
                other => Err(anyhow::anyhow!("no such check {other}")),
            };
            match result {
                Ok(()) => println!("vcan-guest: ok {name}"),
                Err(e) => {
                    failed += 1;
                    println!("vcan-guest: FAIL {name}: {e:#}");
                }
            }
        }
        println!(
            "vcan-guest: {} of {} checks passed",
            CHECKS.len() - failed,
            CHECKS.len()
        );
        failed == 0
    }

    /// On a kernel WITH SocketCAN, a missing or non-CAN interface must be NotFound, not Unsupported.
    fn open_not_found(ifname: &str) -> Result<()> {
        match SocketCanBus::open(ifname) {
            Err(CanError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => {
                ensure!(
                    e.to_string().contains(ifname),
                    "message lacks the name: {e}"
                );
                Ok(())
            }
            other => bail!("open({ifname:?}): expected Io(NotFound), got {other:?}"),
        }
    }

    async fn cansend(arg: &str) -> Result<()> {
        let out = timeout(
            STEP_TIMEOUT,
            Command::new("cansend").args([IF, arg]).output(),
        )
        .await
        .context("cansend timed out")?
        .context("cannot run cansend")?;
        ensure!(
            out.status.success(),
            "cansend {arg} failed: {} {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
        Ok(())
    }

    async fn recv(bus: &mut SocketCanBus) -> Result<Frame> {
        Ok(timeout(STEP_TIMEOUT, bus.recv())
            .await
            .context("no frame within the timeout")??)
    }

    async fn cansend_expect(arg: &str, want: Frame) -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        cansend(arg).await?;
        let got = recv(&mut bus).await?;
        ensure!(got == want, "cansend {arg}: got {got:?}, want {want:?}");
        Ok(())
    }

    async fn cansend_cia406_tpdo() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        cansend("181#78563412").await?;
        let got = recv(&mut bus).await?;
        ensure!(
            got.id() == Id::Standard(StandardId::new(0x181).unwrap()),
            "id {:?}",
            got.id()
        );
        let node_id = got.raw_id() - 0x180;
        let data: [u8; 4] = got.data().try_into().context("TPDO must carry 4 bytes")?;
        let position_counts = u32::from_le_bytes(data);
        ensure!(node_id == 1, "node id {node_id}");
        ensure!(
            position_counts == 0x1234_5678,
            "6004h = {position_counts:#x}"
        );
        Ok(())
    }

    async fn cansend_remote() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        cansend("123#R4").await?;
        cansend("00000123#R3").await?;
        for (raw_id, extended, dlc) in [(0x123, false, 4), (0x123, true, 3)] {
            let got = recv(&mut bus).await?;
            ensure!(
                got.is_remote_frame() && got.raw_id() == raw_id && got.is_extended() == extended,
                "got {got:?}"
            );
            ensure!(
                got.dlc() == dlc && got.data().is_empty(),
                "remote dlc/data: {got:?}"
            );
        }
        Ok(())
    }

    /// `20000004#...` is CAN_ERR_FLAG | CAN_ERR_CRTL with data[1] = CAN_ERR_CRTL_RX_WARNING.
    async fn error_frame_skipped() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        cansend("20000004#0004000000000000").await?;
        cansend("100#AA").await?;
        let got = recv(&mut bus).await?;
        ensure!(
            got == Frame::standard(0x100, &[0xAA]).unwrap(),
            "got {got:?}"
        );
        ensure!(
            bus.error_frames() == 1,
            "error frames counted: {}",
            bus.error_frames()
        );
        Ok(())
    }

    /// The frame as `candump -L` prints it after the interface name (can-utils lib.c
    /// `sprint_canframe`): 3 or 8 upper-case hex id digits, `#`, data bytes, or `R` + dlc.
    fn candump_token(f: &Frame) -> String {
        let id = if f.is_extended() {
            format!("{:08X}", f.raw_id())
        } else {
            format!("{:03X}", f.raw_id())
        };
        let body = if f.is_remote_frame() {
            if f.dlc() > 0 {
                format!("R{}", f.dlc())
            } else {
                "R".to_owned()
            }
        } else {
            f.data().iter().map(|b| format!("{b:02X}")).collect()
        };
        format!("{id}#{body}")
    }

    /// Raw receivers on vcan0, from the kernel's own list: how we know candump has bound its socket
    /// before we send (its stdout says nothing until the first frame).
    fn vcan_receivers() -> Result<usize> {
        let list = std::fs::read_to_string("/proc/net/can/rcvlist_all")
            .context("read /proc/net/can/rcvlist_all")?;
        Ok(list
            .lines()
            .filter(|l| l.split_whitespace().next() == Some(IF))
            .count())
    }

    async fn retrocomp_to_candump() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        let frames = [
            Frame::standard(0x181, &[0x78, 0x56, 0x34, 0x12]).unwrap(),
            Frame::extended(0x18FF_50E5, &[0xDE, 0xAD, 0xBE, 0xEF, 0, 1, 2, 3]).unwrap(),
            Frame::new_remote(StandardId::new(0x123).unwrap(), 4).unwrap(),
            Frame::new_remote(embedded_can::ExtendedId::new(0x1234).unwrap(), 0).unwrap(),
            Frame::standard(0x7FF, &[]).unwrap(),
        ];
        let before = vcan_receivers()?;
        let mut child = Command::new("candump")
            .args(["-L", "-n", &frames.len().to_string(), "-T", "20000", IF])
            .stdout(std::process::Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .context("cannot run candump")?;
        let deadline = tokio::time::Instant::now() + STEP_TIMEOUT;
        while vcan_receivers()? <= before {
            ensure!(
                tokio::time::Instant::now() < deadline,
                "candump never bound to {IF}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        for f in &frames {
            bus.send(f).await?;
        }
        let mut stdout = child.stdout.take().context("candump stdout")?;
        let mut text = String::new();
        timeout(STEP_TIMEOUT, stdout.read_to_string(&mut text))
            .await
            .context("candump did not exit after receiving the frames")??;
        let status = child.wait().await?;
        ensure!(status.success(), "candump: {status}; output:\n{text}");
        // `(1700000000.123456) vcan0 181#78563412`
        let got: Vec<&str> = text
            .lines()
            .filter_map(|l| l.split_whitespace().nth(2))
            .collect();
        let want: Vec<String> = frames.iter().map(candump_token).collect();
        ensure!(
            got == want,
            "candump saw {got:?}, want {want:?}; raw output:\n{text}"
        );
        Ok(())
    }

    /// Two retrocomp sockets on vcan0: 200 frames with a sequence number arrive complete and in
    /// order (vcan delivers synchronously; 200 frames fit the default receive buffer).
    async fn burst_in_order() -> Result<()> {
        const N: u16 = 200;
        let mut tx = SocketCanBus::open(IF)?;
        let mut rx = SocketCanBus::open(IF)?;
        for seq in 0..N {
            let f = Frame::standard(0x200 + (seq % 0x100), &seq.to_be_bytes()).unwrap();
            tx.send(&f).await?;
        }
        for seq in 0..N {
            let got = recv(&mut rx).await?;
            let want = Frame::standard(0x200 + (seq % 0x100), &seq.to_be_bytes()).unwrap();
            ensure!(got == want, "frame {seq}: got {got:?}, want {want:?}");
        }
        Ok(())
    }
}

#[cfg(all(feature = "socketcan", target_os = "linux"))]
fn main() {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("tokio runtime");
    let all_ok = runtime.block_on(guest::run());
    std::process::exit(if all_ok { 0 } else { 1 });
}

#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
fn main() {
    eprintln!("vcan_guest needs Linux and the `socketcan` feature");
    std::process::exit(2);
}
