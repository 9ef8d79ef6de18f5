//! The serial shell of the controller's DNC input ([`crate::controller::dnc`]): the device of
//! `[io.dnc]` opened with tokio-serial (raw, no flow control of the driver: DC1/DC3 are bytes the
//! control itself sends), a reader task that hands every chunk to the simulation task, and the
//! XON/XOFF the input decides written back. With `serve --out DIR`: `dnc.csv`
//! (`t_s,event,line,fill`: received | overrun | taken | xoff | xon; simulated time, buffer fill
//! after the event) and, for any G-code program, `dwell_ends.csv` ([`DwellEnd`]).

use std::io::Write;
use std::path::Path;

use tokio::io::{AsyncReadExt, AsyncWriteExt, WriteHalf};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_serial::{SerialPortBuilderExt, SerialStream};

use crate::World;
use crate::controller::dnc::DncConfig;
use crate::world::DwellEnd;

type Csv = std::io::BufWriter<std::fs::File>;

fn create_csv(dir: &Path, name: &str, header: &str) -> anyhow::Result<Csv> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join(name))?);
    f.write_all(header.as_bytes())?;
    Ok(f)
}

/// The open DNC device.
pub(crate) struct DncPort {
    tx: WriteHalf<SerialStream>,
    rx: mpsc::UnboundedReceiver<Vec<u8>>,
    reader: JoinHandle<()>,
    csv: Option<Csv>,
    sender_gone: bool,
}

impl Drop for DncPort {
    fn drop(&mut self) {
        self.reader.abort();
    }
}

impl DncPort {
    pub(crate) fn open(cfg: &DncConfig, out: Option<&Path>) -> anyhow::Result<Self> {
        let dev = cfg.device.display();
        let port = tokio_serial::new(cfg.device.to_string_lossy(), cfg.baud)
            .flow_control(tokio_serial::FlowControl::None)
            .open_native_async()
            .map_err(|e| anyhow::anyhow!("io.dnc.device {dev}: {e}"))?;
        let (mut rd, tx) = tokio::io::split(port);
        let (chunks, rx) = mpsc::unbounded_channel();
        let reader = tokio::spawn(async move {
            let mut buf = [0u8; 512];
            // A closed sender (EOF, EIO on a pty whose other side went) ends the input; what
            // arrived before stays buffered in the controller.
            while let Ok(n @ 1..) = rd.read(&mut buf).await {
                if chunks.send(buf[..n].to_vec()).is_err() {
                    break;
                }
            }
        });
        let csv = match out {
            Some(dir) => Some(create_csv(dir, "dnc.csv", "t_s,event,line,fill\n")?),
            None => None,
        };
        Ok(Self {
            tx,
            rx,
            reader,
            csv,
            sender_gone: false,
        })
    }

    /// Before a step: what arrived goes into the controller's buffer.
    pub(crate) fn pump_in(&mut self, world: &mut World) {
        let t = world.t_s();
        let Some(d) = world.dnc_mut() else {
            return;
        };
        while let Ok(chunk) = self.rx.try_recv() {
            d.input.receive(&chunk, t);
        }
    }

    /// After a step: XON/XOFF out, the events to `dnc.csv`.
    pub(crate) async fn after_step(&mut self, world: &mut World) -> anyhow::Result<()> {
        let Some(d) = world.dnc_mut() else {
            return Ok(());
        };
        let out = d.input.take_output();
        if !out.is_empty()
            && !self.sender_gone
            && let Err(e) = self.tx.write_all(&out).await
        {
            // The sender closed the line (the transfer ended): the controller runs on what it
            // holds; a sender that comes back gets no XON, as a real control would not send one
            // into a dead line either.
            eprintln!(
                "hil-sim: dnc: XON/XOFF not written at t = {:.3} s: {e}",
                world.t_s()
            );
            self.sender_gone = true;
        }
        let Some(d) = world.dnc_mut() else {
            return Ok(());
        };
        let events = d.input.take_events();
        if let Some(f) = self.csv.as_mut() {
            for e in events {
                writeln!(f, "{:.6},{},{},{}", e.t_s, e.kind.name(), e.line, e.fill)?;
            }
        }
        Ok(())
    }

    /// The transfer's summary on stderr (and the line that stopped the program, if one did).
    pub(crate) fn finish(mut self, world: &mut World) -> anyhow::Result<()> {
        if let Some(f) = self.csv.as_mut() {
            f.flush()?;
        }
        let Some(d) = world.dnc_mut() else {
            return Ok(());
        };
        let c = d.input.counts();
        eprintln!(
            "hil-sim: dnc: {} lines received, {} overrun(s), {} XOFF, buffer fill at most {} of {}",
            c.lines,
            c.overruns,
            c.xoffs,
            c.max_fill,
            d.input.config().buffer_lines
        );
        if let Some(e) = &d.error {
            eprintln!("hil-sim: dnc: program stopped: {e}");
        }
        Ok(())
    }
}

/// `dwell_ends.csv`, created at the first dwell end.
pub(crate) struct DwellLog {
    dir: Option<std::path::PathBuf>,
    csv: Option<Csv>,
}

impl DwellLog {
    pub(crate) fn new(out: Option<&Path>) -> Self {
        Self {
            dir: out.map(Path::to_path_buf),
            csv: None,
        }
    }

    pub(crate) fn after_step(&mut self, world: &mut World) -> anyhow::Result<()> {
        let (Some(d), Some(dir)) = (world.take_dwell_end(), self.dir.as_ref()) else {
            return Ok(());
        };
        if self.csv.is_none() {
            self.csv = Some(create_csv(dir, "dwell_ends.csv", DwellEnd::CSV_HEADER)?);
        }
        let f = self.csv.as_mut().expect("created above");
        f.write_all(d.csv_row().as_bytes())?;
        Ok(())
    }

    pub(crate) fn finish(self) -> anyhow::Result<()> {
        if let Some(mut f) = self.csv {
            f.flush()?;
        }
        Ok(())
    }
}
