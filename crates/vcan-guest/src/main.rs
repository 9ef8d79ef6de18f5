//! The in-guest half of the real-kernel vcan test: runs INSIDE the QEMU guest that
//! `crates/vcan-guest/tests/vcan_qemu.rs` boots (scripts/vcan-qemu/init brings vcan0 up first), never on the host.
//!
//! It checks retrocomp's `SocketCanBus` against the kernel's vcan0 with can-utils as the independent
//! peer, in both directions: `cansend` → `SocketCanBus::recv`, and `SocketCanBus::send` → `candump`.
//! Each check prints `vcan-guest: ok <name>` or `vcan-guest: FAIL <name>: <why>`; the host test
//! requires every name that `vcan_guest --list` prints. Exit status 0 iff all passed.
//!
//! CiA 406 fixture: TPDO1 of node 1 has COB-ID 0x180 + 1 and maps 6004h (position, U32,
//! little-endian, CiA 301 byte order), so `181#78563412` carries 0x1234_5678 counts.

#[cfg(all(feature = "socketcan", target_os = "linux"))]
mod guest {
    use anyhow::{Context, Result, bail, ensure};
    use embedded_can::{Frame as _, Id, StandardId};
    use retrocomp_bus::Health;
    use retrocomp_bus::can::{
        BusState, CanBackendConfig, CanBus, CanError, Frame, IdFilter, SocketCanBus,
    };
    use retrocomp_bus::canopen::{self, CanopenConfig, CanopenSource};
    use retrocomp_gateway::FaultKind;
    use std::time::{Duration, SystemTime};
    use tokio::io::AsyncReadExt;
    use tokio::process::Command;
    use tokio::time::timeout;

    const IF: &str = "vcan0";
    /// Generous: TCG emulation is 10–50× slower than the host.
    const STEP_TIMEOUT: Duration = Duration::from_secs(10);

    /// Every check the host test expects to see passed, in run order.
    pub(crate) const CHECKS: &[&str] = &[
        "open_missing_interface_is_not_found",
        "open_non_can_interface_is_not_found",
        "cansend_cia406_tpdo_to_retrocomp",
        "canopen_source_end_to_end_from_field_toml",
        "cansend_extended_to_retrocomp",
        "cansend_remote_to_retrocomp",
        "cansend_empty_to_retrocomp",
        "cansend_error_frame_is_counted_and_skipped",
        "cansend_canfd_frame_is_not_delivered",
        "retrocomp_to_candump",
        "retrocomp_burst_in_order",
        "kernel_filters_select_ids",
        "recv_timestamp_is_kernel_arrival_time",
        "interface_down_is_an_error_not_a_hang",
        "interface_removed_is_an_error_not_a_hang",
        "error_frames_drive_the_bus_state",
        "gateway_can_source_reconnects_after_interface_down",
    ];

    pub(crate) async fn run() -> bool {
        let mut failed = 0usize;
        for &name in CHECKS {
            let result = match name {
                "open_missing_interface_is_not_found" => open_not_found("rcnone0"),
                "open_non_can_interface_is_not_found" => open_not_found("lo"),
                "cansend_cia406_tpdo_to_retrocomp" => cansend_cia406_tpdo().await,
                "canopen_source_end_to_end_from_field_toml" => canopen_end_to_end().await,
                "cansend_extended_to_retrocomp" => {
                    let want = Frame::extended(0x18FF_50E5, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
                    cansend_expect("18FF50E5#0102030405060708", want).await
                }
                "cansend_remote_to_retrocomp" => cansend_remote().await,
                "cansend_empty_to_retrocomp" => {
                    cansend_expect("7FF#", Frame::standard(0x7FF, &[]).unwrap()).await
                }
                "cansend_error_frame_is_counted_and_skipped" => error_frame_skipped().await,
                "cansend_canfd_frame_is_not_delivered" => canfd_not_delivered().await,
                "retrocomp_to_candump" => retrocomp_to_candump().await,
                "retrocomp_burst_in_order" => burst_in_order().await,
                "kernel_filters_select_ids" => kernel_filters().await,
                "recv_timestamp_is_kernel_arrival_time" => recv_timestamp().await,
                "interface_down_is_an_error_not_a_hang" => interface_down().await,
                "interface_removed_is_an_error_not_a_hang" => interface_removed().await,
                "error_frames_drive_the_bus_state" => error_frames_bus_state().await,
                "gateway_can_source_reconnects_after_interface_down" => {
                    gateway_reconnects_after_down().await
                }
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

    /// The gateway's path as configured in the field TOML: backend = "socketcan" selects
    /// `SocketCanBus` via `can::open`; the CANopen source sends its bring-up (SDO write 6200h
    /// cyclic timer = 10 ms, then NMT start), which candump must see byte for byte; a TPDO from
    /// cansend becomes a sample; with no further PDO the channel goes stale (pdo_timeout_s).
    async fn canopen_end_to_end() -> Result<()> {
        #[derive(serde::Deserialize)]
        struct Field {
            can: CanBackendConfig,
            canopen: CanopenConfig,
        }
        let field: Field = toml::from_str(
            r#"
            [can]
            backend = "socketcan"
            interface = "vcan0"

            [canopen]
            pdo_timeout_s = 0.5

            [[canopen.encoder]]
            channel = "x_mm"
            node_id = 1
            counts_per_mm = 1000.0
            cyclic_ms = 10
            "#,
        )?;
        // SDO expedited download of 2 bytes (0x2B) to 6200h sub 0, value 10 ms; NMT start (01) node 1.
        let bring_up = ["601#2B0062000A000000", "000#0101"];
        let before = vcan_receivers()?;
        let mut dump = Command::new("candump")
            .args(["-L", "-n", "2", "-T", "20000", IF])
            .stdout(std::process::Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .context("cannot run candump")?;
        wait_for_receivers(before).await?;

        let mut bus = retrocomp_bus::can::open(&field.can, None).await?;
        ensure!(
            matches!(bus, retrocomp_bus::can::AnyCanBus::Socketcan(_)),
            "backend = \"socketcan\" opened {bus:?}"
        );
        let mut table = retrocomp_bus::ChannelTable::default();
        let mut src = CanopenSource::new(field.canopen, &mut table);
        let (tx, mut rx) = tokio::sync::mpsc::channel(64);
        let start = std::time::Instant::now();
        let task = tokio::spawn(async move {
            canopen::run(
                &mut bus,
                &mut src,
                move || start.elapsed().as_secs_f64(),
                tx,
            )
            .await
        });

        let mut text = String::new();
        let mut stdout = dump.stdout.take().context("candump stdout")?;
        timeout(STEP_TIMEOUT, stdout.read_to_string(&mut text))
            .await
            .context("candump did not see the bring-up frames")??;
        let got: Vec<&str> = text
            .lines()
            .filter_map(|l| l.split_whitespace().nth(2))
            .collect();
        ensure!(
            got == bring_up,
            "bring-up on the wire: {got:?}, want {bring_up:?}"
        );

        cansend("181#78563412").await?;
        let mut ok_value = None;
        let deadline = tokio::time::Instant::now() + STEP_TIMEOUT;
        let mut went_stale = false;
        while !went_stale {
            let batch = tokio::time::timeout_at(deadline, rx.recv())
                .await
                .context("no Ok-then-Stale samples within the timeout")?
                .context("CANopen source stopped")?;
            for s in batch {
                let name = table.name(s.channel);
                ensure!(name == "x_mm", "unexpected channel {name}");
                match s.health {
                    Health::Ok => ok_value = Some(s.value),
                    Health::Stale if ok_value.is_some() => went_stale = true,
                    _ => {}
                }
            }
        }
        task.abort();
        // 0x12345678 counts / 1000 counts per mm.
        let want_mm = f64::from(0x1234_5678u32) / 1000.0;
        ensure!(
            ok_value == Some(want_mm),
            "decoded {ok_value:?} mm, want {want_mm}"
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

    /// `20000004#...` is CAN_ERR_FLAG | CAN_ERR_CRTL with `data[1]` = CAN_ERR_CRTL_RX_WARNING.
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
        let state = bus.bus_errors().state();
        ensure!(state == BusState::Warning, "after RX_WARNING: {state:?}");
        Ok(())
    }

    /// Let `recv` consume the queued error frames (it returns data frames only): none may arrive.
    async fn settle(bus: &mut SocketCanBus) -> Result<()> {
        let r = timeout(Duration::from_millis(300), bus.recv()).await;
        ensure!(r.is_err(), "a data frame arrived unexpectedly: {r:?}");
        Ok(())
    }

    /// Bus-off cannot happen on vcan, but its error frames can be sent (cansend with CAN_ERR_FLAG):
    /// error-passive (CRTL, `data[1]` = TX_PASSIVE), bus-off with counters (BUSOFF | CNT, TEC in
    /// `data[6]`), restarted; a data frame then still arrives.
    async fn error_frames_bus_state() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        cansend("20000004#0020000000000000").await?;
        settle(&mut bus).await?;
        ensure!(
            bus.bus_errors().state() == BusState::Passive,
            "{:?}",
            bus.bus_errors()
        );
        cansend("20000240#000000000000F803").await?;
        settle(&mut bus).await?;
        let e = bus.bus_errors();
        ensure!(
            e.state() == BusState::BusOff && e.bus_off_events == 1,
            "after BUSOFF: {e:?}"
        );
        ensure!(
            (e.tx_error_count, e.rx_error_count) == (Some(0xF8), Some(3)),
            "counters: {e:?}"
        );
        cansend("20000100#0000000000000000").await?;
        cansend("181#01").await?;
        let got = recv(&mut bus).await?;
        ensure!(got == Frame::standard(0x181, &[1]).unwrap(), "got {got:?}");
        let e = bus.bus_errors();
        ensure!(
            e.state() == BusState::Active && e.error_frames == 3,
            "after RESTARTED: {e:?}"
        );
        Ok(())
    }

    /// The gateway's CAN source (`spawn_sources`, backend = "socketcan") when vcan0 goes down
    /// (ENETDOWN) and up again: it reopens with backoff, the link is `disconnected` meanwhile, and
    /// samples flow again (a TPDO sent after the up arrives) with one reconnect counted.
    async fn gateway_reconnects_after_down() -> Result<()> {
        use retrocomp_gateway::config::FieldConfig;
        use retrocomp_gateway::sources::spawn_sources;
        let text = r#"
            [gateway]
            name = "vcan"
            cycle_ms = 10
            status_listen = "127.0.0.1:0"
            [safety]
            max_correction_um = 60.0
            max_change_um_per_cycle = 0.5
            ramp_um_per_s = 200.0
            stale_hold_s = 0.5
            [direction]
            deadband_mm = 0.005
            switch_time_s = 0.05
            [[axis]]
            name = "x"
            position_channel = "x_mm"
            [can]
            backend = "socketcan"
            interface = "vcan0"
            [canopen]
            pdo_timeout_s = 0.5
            encoder = [{ channel = "x_mm", node_id = 1, counts_per_mm = 1000.0 }]
        "#;
        let cfg = FieldConfig::parse(text, std::path::Path::new("vcan-field.toml"))?;
        let mut feed = spawn_sources(&cfg, std::time::Instant::now()).await?;
        let can = |feed: &retrocomp_gateway::sources::SourceFeed| {
            feed.board.snapshot().into_iter().find(|s| s.name == "can")
        };
        // Resend a TPDO until its value arrives as an Ok sample (the source may be mid-reopen).
        async fn value_arrives(
            feed: &mut retrocomp_gateway::sources::SourceFeed,
            frame: &str,
            want_mm: f64,
        ) -> Result<()> {
            let deadline = tokio::time::Instant::now() + STEP_TIMEOUT * 3;
            loop {
                cansend(frame).await?;
                let wait = tokio::time::Instant::now() + Duration::from_millis(200);
                while let Ok(Some(s)) = tokio::time::timeout_at(wait, feed.samples.recv()).await {
                    if s.health == Health::Ok && s.value == want_mm {
                        return Ok(());
                    }
                }
                ensure!(
                    tokio::time::Instant::now() < deadline,
                    "{want_mm} mm never arrived"
                );
            }
        }
        value_arrives(&mut feed, "181#E8030000", 1.0).await?;
        ip_link("down").await?;
        let deadline = tokio::time::Instant::now() + STEP_TIMEOUT;
        while can(&feed).is_some_and(|s| s.connected) {
            ensure!(
                tokio::time::Instant::now() < deadline,
                "link never reported down"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let down = can(&feed).context("no `can` source on the board")?;
        ensure!(
            down.faults
                .iter()
                .any(|(k, _)| *k == FaultKind::Disconnected),
            "no disconnected fault: {down:?}"
        );
        ip_link("up").await?;
        value_arrives(&mut feed, "181#D0070000", 2.0).await?;
        // The source reports the link up when the first frame after the reopen arrives.
        let deadline = tokio::time::Instant::now() + STEP_TIMEOUT;
        loop {
            let st = can(&feed).context("no `can` source on the board")?;
            if st.connected {
                ensure!(
                    st.reconnects == 1 && st.faults.is_empty(),
                    "after up: {st:?}"
                );
                return Ok(());
            }
            ensure!(
                tokio::time::Instant::now() < deadline,
                "link never reported up: {st:?}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// vcan0 has the CAN FD MTU (72), so peers may send FD frames; our classic CAN_RAW socket does
    /// not enable CAN_RAW_FD_FRAMES, so the kernel must not hand them to us (net/can/raw.c
    /// `raw_rcv`), and the next classic frame still arrives.
    async fn canfd_not_delivered() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        cansend("181##1112233445566778899AABB").await?;
        cansend("101#01").await?;
        let got = recv(&mut bus).await?;
        ensure!(got == Frame::standard(0x101, &[1]).unwrap(), "got {got:?}");
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

    /// Waits until the kernel lists more raw receivers on vcan0 than `before` (a peer has bound).
    async fn wait_for_receivers(before: usize) -> Result<()> {
        let deadline = tokio::time::Instant::now() + STEP_TIMEOUT;
        while vcan_receivers()? <= before {
            ensure!(
                tokio::time::Instant::now() < deadline,
                "candump never bound to {IF}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        Ok(())
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
        wait_for_receivers(before).await?;
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

    /// Two retrocomp sockets on vcan0: 4 bursts of 50 frames with a sequence number arrive complete
    /// and in order. vcan delivers synchronously into the receiver's socket queue; a burst of 50
    /// stays far below the default receive buffer (~270 classic frames with rmem_default 212992),
    /// so a drop here is a real fault, not buffer sizing.
    async fn burst_in_order() -> Result<()> {
        const BURST: u16 = 50;
        const BURSTS: u16 = 4;
        let mut tx = SocketCanBus::open(IF)?;
        let mut rx = SocketCanBus::open(IF)?;
        let frame = |seq: u16| Frame::standard(0x200 + (seq % 0x100), &seq.to_be_bytes()).unwrap();
        for burst in 0..BURSTS {
            let seqs = burst * BURST..(burst + 1) * BURST;
            for seq in seqs.clone() {
                tx.send(&frame(seq)).await?;
            }
            for seq in seqs {
                let got = recv(&mut rx).await?;
                ensure!(
                    got == frame(seq),
                    "frame {seq}: got {got:?}, want {:?}",
                    frame(seq)
                );
            }
        }
        Ok(())
    }

    /// Standard 0x180/0x780 passes the TPDO1s only: a standard 0x281 and an extended id with the
    /// same low bits (0x0000_0181) must be dropped by the kernel, before they reach us.
    async fn kernel_filters() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        ensure!(
            bus.set_filters(&[]).is_err(),
            "an empty filter list must be refused"
        );
        bus.set_filters(&[IdFilter {
            id: Id::Standard(StandardId::new(0x180).unwrap()),
            mask: 0x780,
        }])?;
        for arg in ["281#01", "00000181#02", "181#03", "1FF#04"] {
            cansend(arg).await?;
        }
        for want in [(0x181, 3u8), (0x1FF, 4)] {
            let got = recv(&mut bus).await?;
            let want = Frame::standard(want.0, &[want.1]).unwrap();
            ensure!(got == want, "filtered: got {got:?}, want {want:?}");
        }
        bus.accept_all()?;
        cansend("281#05").await?;
        let got = recv(&mut bus).await?;
        ensure!(
            got == Frame::standard(0x281, &[5]).unwrap(),
            "after accept_all: {got:?}"
        );
        Ok(())
    }

    async fn recv_timestamp() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        let before = SystemTime::now();
        cansend("181#0102").await?;
        let (got, at) = timeout(STEP_TIMEOUT, bus.recv_timestamped())
            .await
            .context("no frame within the timeout")??;
        let after = SystemTime::now();
        ensure!(
            got == Frame::standard(0x181, &[1, 2]).unwrap(),
            "got {got:?}"
        );
        ensure!(
            before <= at && at <= after,
            "kernel timestamp {at:?} outside [{before:?}, {after:?}]"
        );
        Ok(())
    }

    async fn ip_link(state: &str) -> Result<()> {
        ip(&["link", "set", IF, state]).await
    }

    /// The kernel reports ENETDOWN to sockets bound to an interface taken down (net/can/raw.c
    /// `raw_notify`); recv and send must return it, not hang, and the socket works again once
    /// the interface is back up.
    async fn interface_down() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        ip_link("down").await?;
        let down = async {
            let recv_result = timeout(STEP_TIMEOUT, bus.recv()).await;
            let send_result = bus.send(&Frame::standard(0x181, &[1]).unwrap()).await;
            (recv_result, send_result)
        }
        .await;
        ip_link("up").await?;
        match down.0 {
            Err(_) => bail!("recv hung on a downed interface"),
            Ok(Err(CanError::Io(e))) => ensure!(
                e.kind() == std::io::ErrorKind::NetworkDown && e.to_string().contains(IF),
                "recv on a downed interface: {e}"
            ),
            Ok(other) => bail!("recv on a downed interface: expected ENETDOWN, got {other:?}"),
        }
        match down.1 {
            Err(CanError::Io(e)) if e.kind() == std::io::ErrorKind::NetworkDown => {}
            other => bail!("send on a downed interface: expected ENETDOWN, got {other:?}"),
        }
        cansend("181#07").await?;
        let got = recv(&mut bus).await?;
        ensure!(
            got == Frame::standard(0x181, &[7]).unwrap(),
            "after up: {got:?}"
        );
        Ok(())
    }

    async fn ip(args: &[&str]) -> Result<()> {
        let status = Command::new("ip").args(args).status().await?;
        ensure!(status.success(), "ip {}: {status}", args.join(" "));
        Ok(())
    }

    /// Deleting the interface unbinds every socket (ENODEV): recv must say so, not hang. vcan0 is
    /// re-created afterwards so the check order does not matter.
    async fn interface_removed() -> Result<()> {
        let mut bus = SocketCanBus::open(IF)?;
        ip(&["link", "del", IF]).await?;
        let result = timeout(STEP_TIMEOUT, bus.recv()).await;
        ip(&["link", "add", "dev", IF, "type", "vcan"]).await?;
        ip(&["link", "set", IF, "up"]).await?;
        match result {
            Err(_) => bail!("recv hung on a deleted interface"),
            Ok(Err(CanError::Io(e))) => ensure!(
                e.kind() == std::io::ErrorKind::NotFound && e.to_string().contains("removed"),
                "recv on a deleted interface: {e}"
            ),
            Ok(other) => bail!("recv on a deleted interface: expected NotFound, got {other:?}"),
        }
        // A fresh open on the re-created interface works.
        let mut bus = SocketCanBus::open(IF)?;
        cansend("181#08").await?;
        let got = recv(&mut bus).await?;
        ensure!(
            got == Frame::standard(0x181, &[8]).unwrap(),
            "after re-create: {got:?}"
        );
        Ok(())
    }
}

#[cfg(all(feature = "socketcan", target_os = "linux"))]
fn main() {
    // `--list`: the check names, one per line, for the host test (runs anywhere, needs no CAN).
    if std::env::args().nth(1).as_deref() == Some("--list") {
        for name in guest::CHECKS {
            println!("{name}");
        }
        return;
    }
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
