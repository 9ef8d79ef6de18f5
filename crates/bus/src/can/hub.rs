//! A socketcand-protocol hub: a userspace CAN bus on TCP that tests and the simulator start in-process.
//!
//! Every client that completes the rawmode handshake (`< hi >`, `< open BUS >`, `< rawmode >`) joins the
//! bus named in `open`; each frame a client sends is delivered to every *other* client of the same bus
//! (no echo to the sender, like socketcand and a real CAN controller without loopback). python-can's
//! `socketcand` interface and [`super::socketcand_bus::SocketcandBus`] are both clients.
//!
//! Timestamps in `< frame … >` are the hub's receive time in seconds since the Unix epoch, as
//! socketcand writes kernel timestamps. A client that falls more than [`HUB_QUEUE`] frames behind loses
//! the oldest ones; the loss is counted in [`HubStats::frames_dropped`] and reported to that client as
//! `< error lagged N >`.
//!
//! Connections are kept by the listener policy (`crate::listen`, [`hub_policy`]): caps, idle
//! timeout, descriptor reserve, accept backoff, restart.

use super::Frame;
use super::socketcand::{Decoder, Message, encode_into};
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};
use tokio::io::{AsyncReadExt, AsyncWriteExt, BufWriter, WriteHalf};
use tokio::net::TcpStream;
use tokio::sync::broadcast;
use tokio::task::AbortHandle;

use crate::listen::{Conn, Handler, IdleStream, ListenPolicy, ListenerHealth, Spec, listen};

/// Frames a client may fall behind before it loses some.
pub(crate) const HUB_QUEUE: usize = 8192;

/// Counters, readable while the hub runs.
#[derive(Debug, Default)]
pub struct HubStats {
    pub clients_connected: AtomicU64,
    pub frames_in: AtomicU64,
    pub frames_out: AtomicU64,
    pub frames_dropped: AtomicU64,
    pub bad_messages: AtomicU64,
}

#[derive(Clone, Debug)]
struct Routed {
    from_client: u64,
    bus: Arc<str>,
    frame: Frame,
    t_s: f64,
}

/// A running hub; dropping it stops the listener and disconnects every client.
#[derive(Debug)]
pub struct Hub {
    addr: SocketAddr,
    stats: Arc<HubStats>,
    health: ListenerHealth,
    task: AbortHandle,
}

/// The hub's listener policy: everything local, so the per-peer cap is the whole cap, and a long
/// idle time (a CAN bus may carry nothing for minutes, and socketcand has no keep-alive).
pub(crate) fn hub_policy() -> ListenPolicy {
    ListenPolicy {
        max_connections: 64,
        max_connections_per_peer: 64,
        idle_timeout_s: 600.0,
        ..ListenPolicy::default()
    }
}

impl Hub {
    /// Listen on `addr` (tests use `127.0.0.1:0`) and serve until dropped.
    pub async fn start(addr: SocketAddr) -> std::io::Result<Hub> {
        let stats = Arc::new(HubStats::default());
        let l = listen(addr, spec(Arc::clone(&stats))).await?;
        let (addr, health) = (l.addr, l.health.clone());
        let task = l.into_task().abort_handle();
        Ok(Hub {
            addr,
            stats,
            health,
            task,
        })
    }

    /// Like [`Hub::start`], on a dedicated OS thread with its own current-thread runtime, so the
    /// bus never waits behind the caller's busy tasks; `priority` asks `SCHED_FIFO` for that thread
    /// (see `crate::realtime`; refused → a WARN line and the normal scheduler). The thread ends
    /// when the hub is dropped.
    pub fn start_on_thread(addr: SocketAddr, priority: Option<u8>) -> std::io::Result<Hub> {
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        crate::realtime::spawn_thread("socketcand-hub", priority, move || {
            rt.block_on(async move {
                let stats = Arc::new(HubStats::default());
                match listen(addr, spec(Arc::clone(&stats))).await {
                    Ok(l) => {
                        let (addr, health) = (l.addr, l.health.clone());
                        let task = l.into_task();
                        let _ = ready_tx.send(Ok(Hub {
                            addr,
                            stats,
                            health,
                            task: task.abort_handle(),
                        }));
                        // Runs until Hub::drop aborts it.
                        let _ = task.await;
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                    }
                }
            });
        })?;
        ready_rx
            .recv()
            .map_err(|_| std::io::Error::other("the hub thread ended while starting"))?
    }

    /// Shorthand for a hub on an ephemeral loopback port.
    pub async fn start_loopback() -> std::io::Result<Hub> {
        Self::start(SocketAddr::from(([127, 0, 0, 1], 0))).await
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    pub fn stats(&self) -> &HubStats {
        &self.stats
    }

    /// The listener's faults (refusals, restarts).
    pub fn health(&self) -> &ListenerHealth {
        &self.health
    }
}

impl Drop for Hub {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn spec(stats: Arc<HubStats>) -> Spec {
    let (tx, _) = broadcast::channel::<Routed>(HUB_QUEUE);
    let next_id = Arc::new(AtomicU64::new(0));
    let handler: Handler = Arc::new(move |conn: Conn| {
        let id = next_id.fetch_add(1, Ordering::Relaxed) + 1;
        stats.clients_connected.fetch_add(1, Ordering::Relaxed);
        let (tx, stats) = (tx.clone(), Arc::clone(&stats));
        Box::pin(async move {
            let peer = conn.peer;
            if let Err(e) = serve_client(conn.stream, id, tx, &stats).await {
                tracing::debug!(%peer, "socketcand hub client ended: {e}");
            }
        })
    });
    Spec {
        name: "socketcand_hub",
        policy: hub_policy(),
        refusal: b"< error too many clients >",
        handler,
    }
}

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

enum Phase {
    AwaitOpen,
    AwaitRawMode(Arc<str>),
    Raw(Arc<str>, broadcast::Receiver<Routed>),
}

type Writer = BufWriter<WriteHalf<IdleStream<TcpStream>>>;

async fn serve_client(
    stream: IdleStream<TcpStream>,
    id: u64,
    tx: broadcast::Sender<Routed>,
    stats: &HubStats,
) -> std::io::Result<()> {
    stream.get_ref().set_nodelay(true)?;
    let (mut rd, wr) = tokio::io::split(stream);
    let mut wr = BufWriter::with_capacity(64 * 1024, wr);
    let mut out = String::with_capacity(4096);
    // python-can compares each handshake reply to one recv(): every reply is its own flushed write.
    reply(&mut wr, &mut out, &Message::Hi).await?;
    let mut phase = Phase::AwaitOpen;
    let mut dec = Decoder::new();
    let mut buf = vec![0u8; 16 * 1024];
    loop {
        let routed = match &mut phase {
            Phase::Raw(_, rx) => {
                tokio::select! {
                    n = rd.read(&mut buf) => Err(n?),
                    r = rx.recv() => Ok(r),
                }
            }
            _ => Err(rd.read(&mut buf).await?),
        };
        match routed {
            Err(0) => return Ok(()),
            Err(n) => {
                dec.push(&buf[..n]);
                while let Some(msg) = dec.next_message() {
                    let Ok(msg) = msg else {
                        stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                        continue;
                    };
                    phase = handle(msg, phase, id, &tx, stats, &mut wr, &mut out).await?;
                }
            }
            Ok(r) => {
                let Phase::Raw(bus, rx) = &mut phase else {
                    unreachable!("frames are only received in rawmode")
                };
                out.clear();
                let mut next = Some(r);
                let mut batch = 0;
                // Drain what is queued into one write: a syscall per frame would cap throughput.
                while let Some(r) = next.take() {
                    match r {
                        Ok(f) if f.from_client != id && f.bus == *bus => {
                            let m = Message::Frame {
                                frame: f.frame,
                                t_s: f.t_s,
                            };
                            encode_into(&mut out, &m);
                            stats.frames_out.fetch_add(1, Ordering::Relaxed);
                        }
                        Ok(_) => {}
                        Err(broadcast::error::RecvError::Lagged(n)) => {
                            stats.frames_dropped.fetch_add(n, Ordering::Relaxed);
                            encode_into(&mut out, &Message::Error(format!("lagged {n}")));
                        }
                        Err(broadcast::error::RecvError::Closed) => return Ok(()),
                    }
                    batch += 1;
                    if batch < 512 {
                        match rx.try_recv() {
                            Ok(f) => next = Some(Ok(f)),
                            Err(broadcast::error::TryRecvError::Lagged(n)) => {
                                next = Some(Err(broadcast::error::RecvError::Lagged(n)));
                            }
                            Err(_) => {}
                        }
                    }
                }
                wr.write_all(out.as_bytes()).await?;
                wr.flush().await?;
            }
        }
    }
}

async fn reply(wr: &mut Writer, out: &mut String, msg: &Message) -> std::io::Result<()> {
    out.clear();
    encode_into(out, msg);
    wr.write_all(out.as_bytes()).await?;
    wr.flush().await
}

async fn handle(
    msg: Message,
    phase: Phase,
    id: u64,
    tx: &broadcast::Sender<Routed>,
    stats: &HubStats,
    wr: &mut Writer,
    out: &mut String,
) -> std::io::Result<Phase> {
    Ok(match (msg, phase) {
        (Message::Open(bus), Phase::AwaitOpen) => {
            reply(wr, out, &Message::Ok).await?;
            Phase::AwaitRawMode(bus.into())
        }
        (Message::RawMode, Phase::AwaitRawMode(bus)) => {
            // Subscribe before acknowledging so no frame sent after our `< ok >` is missed, and
            // write nothing before the `< ok >` (python-can's handshake reads it alone).
            let rx = tx.subscribe();
            reply(wr, out, &Message::Ok).await?;
            Phase::Raw(bus, rx)
        }
        (Message::Send(frame), Phase::Raw(bus, rx)) => {
            stats.frames_in.fetch_add(1, Ordering::Relaxed);
            // No other client: the frame goes nowhere, as on a bus with no other node.
            let _ = tx.send(Routed {
                from_client: id,
                bus: Arc::clone(&bus),
                frame,
                t_s: now_s(),
            });
            Phase::Raw(bus, rx)
        }
        (Message::Echo, p) => {
            reply(wr, out, &Message::Echo).await?;
            p
        }
        (other, p) => {
            stats.bad_messages.fetch_add(1, Ordering::Relaxed);
            let text = format!("unexpected {}", super::socketcand::encode(&other));
            reply(wr, out, &Message::Error(text.replace(['<', '>'], ""))).await?;
            p
        }
    })
}
