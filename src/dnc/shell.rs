//! The async shell of the DNC drip-feed: the controller's serial port (tokio-serial, settings from
//! `[dnc]`), the program source (a file, a TCP connection from a DNC sender, or the sender's
//! serial port, held back with XON/XOFF while the controller is slower), the live samples the
//! model reads, and the CSV send log (flushed per block, so an interrupted transfer's log is
//! complete). The decisions are the core's (`core.rs`); faults and status are `faults.rs`'s.

use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use retrocomp_bus::Sample;
use retrocomp_bus::modbus::Parity;
use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncReadExt, AsyncWriteExt, BufReader, Lines};
use tokio::sync::mpsc;
use tokio_serial::{SerialPort, SerialPortBuilderExt, SerialStream};

use super::core::{DncCore, DncError, LOG_HEADER, XOFF, XON};
use super::faults::{DncFaults, StatusTx};
use super::live::LiveCorrections;
use retrocomp_gateway::sinks::dnc::{DncSection, Flow};

/// Where the program comes from.
#[derive(Clone, Debug)]
pub enum ProgramSource {
    File(PathBuf),
    /// Listen on this address and take the program from the first connection.
    Tcp(std::net::SocketAddr),
    /// The DNC sender's serial port (same settings as the controller's).
    Serial(String),
}

/// How a transfer ended.
#[derive(Debug, Default)]
pub struct DncSummary {
    pub blocks_sent: u64,
    pub stalls: u64,
    pub model_faults: u64,
    pub guard_limited: u64,
    /// Set when the transfer did not complete: the block to resume from and why.
    pub interrupted: Option<(u64, String)>,
    /// The last block sent with a compensated end point: its line and the correction it carried
    /// per axis X, Y, Z (µm). The control holds nothing else of the box's.
    pub last_correction: Option<(u64, [f64; 3])>,
}

/// Open a serial device with the `[dnc]` link settings. XON/XOFF is read by the box itself (the
/// core stops at the next line boundary); RTS/CTS is the driver's.
pub(crate) fn open_port(dev: &str, s: &DncSection) -> std::io::Result<SerialStream> {
    let parity = match s.parity {
        Parity::None => tokio_serial::Parity::None,
        Parity::Even => tokio_serial::Parity::Even,
        Parity::Odd => tokio_serial::Parity::Odd,
    };
    let flow = match s.flow {
        Flow::XonXoff => tokio_serial::FlowControl::None,
        Flow::RtsCts => tokio_serial::FlowControl::Hardware,
    };
    tokio_serial::new(dev, s.baud)
        .parity(parity)
        .data_bits(if s.data_bits == 7 {
            tokio_serial::DataBits::Seven
        } else {
            tokio_serial::DataBits::Eight
        })
        .stop_bits(if s.stop_bits == 2 {
            tokio_serial::StopBits::Two
        } else {
            tokio_serial::StopBits::One
        })
        .flow_control(flow)
        .open_native_async()
        .map_err(std::io::Error::other)
}

type LineSource = Lines<BufReader<Box<dyn AsyncRead + Unpin>>>;

/// The program's lines, and the sender port to hold back (serial sender only).
async fn open_source(
    src: &ProgramSource,
    s: &DncSection,
) -> std::io::Result<(LineSource, Option<tokio::io::WriteHalf<SerialStream>>)> {
    let (read, hold): (Box<dyn AsyncRead + Unpin>, _) = match src {
        ProgramSource::File(p) => (Box::new(tokio::fs::File::open(p).await?), None),
        ProgramSource::Tcp(addr) => {
            let l = tokio::net::TcpListener::bind(addr).await?;
            eprintln!("dnc: waiting for the DNC sender on tcp:{}", l.local_addr()?);
            let (conn, peer) = l.accept().await?;
            eprintln!("dnc: sender connected from {peer}");
            (Box::new(conn), None)
        }
        ProgramSource::Serial(dev) => {
            let (r, w) = tokio::io::split(open_port(dev, s)?);
            (Box::new(r), Some(w))
        }
    };
    Ok((BufReader::new(read).lines(), hold))
}

/// The live side of a transfer: the sources' samples for the model and their clock, and where
/// the status snapshots go.
#[derive(Debug)]
pub struct DncIo {
    pub samples: Option<mpsc::Receiver<Sample>>,
    /// The sources' epoch (their samples' `t_s` count from it): blocks are judged on that clock.
    pub epoch: Instant,
    /// The status endpoint's channel (`/status`, `/metrics`), if one is served.
    pub status: Option<StatusTx>,
}

/// Stream the program to the controller on `port_dev` until it is sent, refused, or interrupted
/// (SIGINT). `io.samples` feed the live model; `log` receives one row per block sent.
pub async fn run_dnc(
    s: &DncSection,
    port_dev: &str,
    source: &ProgramSource,
    core: &mut DncCore<'_>,
    live: &LiveCorrections,
    io: DncIo,
    log: &mut dyn Write,
) -> std::io::Result<DncSummary> {
    let DncIo {
        mut samples,
        epoch,
        status,
    } = io;
    let mut faults = DncFaults::new(status);
    let now = || epoch.elapsed().as_secs_f64();
    let port = open_port(port_dev, s)?;
    let (mut lines, mut hold) = open_source(source, s).await?;
    let mut port = port;
    writeln!(log, "{LOG_HEADER}")?;
    let mut sum = DncSummary::default();
    let (mut line_no, mut sender_held, mut told_waiting) = (0u64, false, false);
    let mut buf = [0u8; 256];
    // One character on the wire: start bit, data bits, parity, stop bits.
    let bits =
        1 + u32::from(s.data_bits) + u32::from(s.parity != Parity::None) + u32::from(s.stop_bits);
    let char_s = f64::from(bits) / f64::from(s.baud);
    let mut busy_until = 0.0;
    // Registered once: a SIGINT that arrives while a line is being written is not lost.
    let mut sigint = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())?;
    let interrupted = |core: &DncCore<'_>, why: String| Some((core.resume_point(), why));
    while !core.done() {
        faults.stall(core.poll_stall(now()), &mut sum, now());
        faults.publish(live, &sum, now());
        if s.flow == Flow::RtsCts {
            // The driver holds output while CTS is low; the core must know to judge a stall.
            let cts = port.read_clear_to_send().map_err(std::io::Error::other)?;
            core.flow(!cts, now());
        }
        // Paced at the line's character rate: what the box wrote is on the wire before the next
        // line, so a DC3 stops it within one line even where the OS buffers more (a pty, a
        // USB adapter's FIFO).
        let ready = if now() < busy_until {
            None
        } else {
            match core.next_to_send(now()) {
                Ok(b) => b.map(<[u8]>::to_vec),
                Err(e) => {
                    match e {
                        DncError::LineTooLong { .. } => faults.line_refused(now()),
                        DncError::NoInputs { .. } => faults.inputs_refused(now()),
                        _ => {}
                    }
                    faults.publish(live, &sum, now());
                    sum.interrupted = interrupted(core, e.to_string());
                    return Ok(sum);
                }
            }
        };
        if let Some(bytes) = ready {
            AsyncWriteExt::write_all(&mut port, &bytes).await?;
            AsyncWriteExt::flush(&mut port).await?;
            busy_until = now() + bytes.len() as f64 * char_s;
            if let Some(b) = core.sent(now()) {
                sum.blocks_sent += 1;
                if let Some(a) = &b.applied {
                    sum.last_correction = Some((b.line, a.correction_um));
                }
                faults.block(live, &mut sum, b.line, now());
                writeln!(log, "{}", b.csv_row())?;
                log.flush()?;
            }
            continue;
        }
        if !told_waiting && let Some(why) = core.waiting_for_inputs() {
            eprintln!(
                "dnc: waiting up to {} s (dnc.start_timeout_s) for the model's inputs before the first line: {why}",
                s.start_timeout_s
            );
            told_waiting = true;
        }
        hold_sender(hold.as_mut(), core.wants_input(), &mut sender_held).await?;
        let tick = core
            .stall_deadline_s()
            .map_or(0.5, |d| d - now())
            .min(core.lead_release_s().map_or(0.5, |r| r - now()))
            .min(busy_until - now())
            .clamp(0.001, 0.5);
        let tick = if s.flow == Flow::RtsCts {
            tick.min(0.01)
        } else {
            tick
        };
        tokio::select! {
            // The control's bytes first: a DC3 already received is read before the timer that
            // lets the next line go (unbiased, tokio picks among ready branches at random, so a
            // line could go out after an XOFF that was already waiting to be read).
            biased;
            r = port.read(&mut buf) => {
                let n = r?;
                if n == 0 {
                    sum.interrupted = interrupted(core, "the controller's port closed".into());
                    return Ok(sum);
                }
                core.on_bytes(&buf[..n], now());
            }
            l = lines.next_line(), if core.wants_input() => match l? {
                Some(text) => {
                    line_no += 1;
                    if let Err(e) = core.feed_line(line_no, &text) {
                        sum.interrupted = interrupted(core, e.to_string());
                        return Ok(sum);
                    }
                }
                None => core.end_of_input(),
            },
            Some(smp) = async { samples.as_mut()?.recv().await }, if samples.is_some() => {
                live.observe(&smp);
            }
            _ = tokio::time::sleep(Duration::from_secs_f64(tick)) => {}
            _ = sigint.recv() => {
                sum.interrupted = interrupted(core, "interrupted (SIGINT)".into());
                return Ok(sum);
            }
        }
    }
    Ok(sum)
}

/// Hold the serial sender back (XOFF) while the core has a line waiting; let it go (XON) when
/// the core wants the next one. `held`: what the sender was last told.
async fn hold_sender(
    hold: Option<&mut tokio::io::WriteHalf<SerialStream>>,
    want: bool,
    held: &mut bool,
) -> std::io::Result<()> {
    if let Some(h) = hold
        && want == *held
    {
        h.write_all(&[if want { XON } else { XOFF }]).await?;
        *held = !want;
    }
    Ok(())
}
