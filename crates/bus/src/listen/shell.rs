//! The async shell of the listener policy: [`listen`] binds, then a supervisor task runs the
//! accept loop and restarts it (a fault, [`ListenerHealth::failed`]) if it ever ends; connections
//! live on their own tasks, so a restart drops none of them (the controller's link included), and
//! they all end when the [`Listening`] handle is dropped. Accept errors back off exponentially from
//! 10 ms to 1 s (one fault episode, never one line per error: an EMFILE flood cannot spin).
//! Admitted connections are wrapped in an [`IdleStream`] that fails with `TimedOut` after the
//! policy's idle time without a byte either way.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio::time::{Instant, Sleep};

use super::{Admissions, ListenPolicy, ListenerHealth, Refusal};
use crate::Backoff;

/// One admitted connection, handed to the listener's [`Handler`].
#[derive(Debug)]
pub struct Conn {
    pub stream: IdleStream<TcpStream>,
    pub peer: SocketAddr,
    /// The peer is on `allow_writes_from`.
    pub may_write: bool,
    /// The listener's faults (a handler reports refused writes here).
    pub health: ListenerHealth,
}

/// Serves one connection; the admission is released when its future ends.
pub type Handler = Arc<dyn Fn(Conn) -> Pin<Box<dyn Future<Output = ()> + Send>> + Send + Sync>;

/// What a listener is and does.
#[derive(Clone)]
pub struct Spec {
    /// For logs and fault sources (`listener.<name>`).
    pub name: &'static str,
    pub policy: ListenPolicy,
    /// Written (best effort, never waited on) to a refused connection before it is closed.
    pub refusal: &'static [u8],
    pub handler: Handler,
}

impl std::fmt::Debug for Spec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Spec")
            .field("name", &self.name)
            .field("policy", &self.policy)
            .finish_non_exhaustive()
    }
}

/// A running listener; dropping it stops it and ends every connection it admitted.
#[derive(Debug)]
pub struct Listening {
    pub addr: SocketAddr,
    pub health: ListenerHealth,
    task: Option<JoinHandle<()>>,
}

impl Listening {
    /// The supervisor task (for a caller that runs it to completion on its own runtime); aborting
    /// it stops the listener.
    pub(crate) fn into_task(mut self) -> JoinHandle<()> {
        self.task
            .take()
            .expect("a Listening always holds its task until dropped")
    }
}

impl Drop for Listening {
    fn drop(&mut self) {
        if let Some(t) = &self.task {
            t.abort();
        }
    }
}

/// Bind `addr` and serve with `spec` until the returned handle is dropped.
pub async fn listen(addr: SocketAddr, spec: Spec) -> io::Result<Listening> {
    let health = ListenerHealth::new(spec.name);
    listen_with(addr, spec, health).await
}

/// [`listen`], reporting into `health` (made before the handler needs it).
pub async fn listen_with(
    addr: SocketAddr,
    spec: Spec,
    health: ListenerHealth,
) -> io::Result<Listening> {
    let listener = TcpListener::bind(addr).await?;
    let addr = listener.local_addr()?;
    if spec.policy.fd_reserve > 0 {
        raise_nofile_soft_limit();
    }
    let task = tokio::spawn(supervise(listener, addr, spec, health.clone()));
    Ok(Listening {
        addr,
        health,
        task: Some(task),
    })
}

const ACCEPT_RETRY_MIN: Duration = Duration::from_millis(10);
const ACCEPT_RETRY_MAX: Duration = Duration::from_secs(1);

/// Run the accept loop; if it ends, raise the fault, re-bind the same address and run it again.
async fn supervise(listener: TcpListener, addr: SocketAddr, spec: Spec, health: ListenerHealth) {
    // Dropped with this task: every connection and accept loop sees `changed()` fail and ends.
    let (_stop_tx, stop_rx) = watch::channel(());
    let admissions = Arc::new(Mutex::new(Admissions::default()));
    let mut listener = Some(listener);
    let mut backoff = Backoff::new(ACCEPT_RETRY_MIN, ACCEPT_RETRY_MAX);
    loop {
        let l = match listener.take() {
            Some(l) => l,
            None => match TcpListener::bind(addr).await {
                Ok(l) => l,
                Err(e) => {
                    health.failed(&format!("re-binding {addr}: {e}"));
                    tokio::time::sleep(backoff.next_delay()).await;
                    continue;
                }
            },
        };
        let run = tokio::spawn(accept_loop(
            l,
            spec.clone(),
            health.clone(),
            Arc::clone(&admissions),
            stop_rx.clone(),
        ));
        let why = match run.await {
            Ok(()) => "the accept loop returned".to_string(),
            Err(e) => format!("the accept loop panicked: {e}"),
        };
        health.failed(&why);
        tokio::time::sleep(backoff.next_delay()).await;
    }
}

async fn accept_loop(
    listener: TcpListener,
    spec: Spec,
    health: ListenerHealth,
    admissions: Arc<Mutex<Admissions>>,
    mut stop: watch::Receiver<()>,
) {
    let mut backoff = Backoff::new(ACCEPT_RETRY_MIN, ACCEPT_RETRY_MAX);
    let idle = Duration::from_secs_f64(spec.policy.idle_timeout_s);
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            _ = stop.changed() => return,
        };
        let (stream, peer) = match accepted {
            Ok(x) => x,
            // The peer gave up before we accepted: nothing wrong on our side.
            Err(e) if e.kind() == io::ErrorKind::ConnectionAborted => continue,
            Err(e) => {
                health.refusing(Some(Refusal::AcceptError));
                let delay = backoff.next_delay();
                tracing::debug!(listener = spec.name, error = %e, backoff = ?delay, "accept failed");
                tokio::time::sleep(delay).await;
                continue;
            }
        };
        backoff.reset();
        let fds = (spec.policy.fd_reserve > 0)
            .then(|| open_fds().zip(nofile_soft_limit()))
            .flatten();
        let admitted = admissions.lock().unwrap_or_else(|e| e.into_inner()).admit(
            &spec.policy,
            peer.ip(),
            fds,
        );
        if let Err(r) = admitted {
            health.refusing(Some(r));
            let _ = stream.try_write(spec.refusal);
            continue;
        }
        health.refusing(None);
        let conn = Conn {
            stream: IdleStream::new(stream, idle),
            peer,
            may_write: spec.policy.may_write(peer.ip()),
            health: health.clone(),
        };
        let serve = (spec.handler)(conn);
        let (admissions, policy, mut stop) =
            (Arc::clone(&admissions), spec.policy.clone(), stop.clone());
        tokio::spawn(async move {
            tokio::select! {
                () = serve => {}
                _ = stop.changed() => {}
            }
            admissions
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .release(&policy, peer.ip());
        });
    }
}

/// A stream that fails with `TimedOut` once no byte has moved either way for its idle time.
#[derive(Debug)]
pub struct IdleStream<S> {
    inner: S,
    idle: Duration,
    deadline: Pin<Box<Sleep>>,
}

impl<S> IdleStream<S> {
    pub fn new(inner: S, idle: Duration) -> Self {
        IdleStream {
            inner,
            idle,
            deadline: Box::pin(tokio::time::sleep(idle)),
        }
    }

    pub fn get_ref(&self) -> &S {
        &self.inner
    }

    fn touch(&mut self) {
        let at = Instant::now() + self.idle;
        self.deadline.as_mut().reset(at);
    }

    fn poll_idle<T>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<T>> {
        match self.deadline.as_mut().poll(cx) {
            Poll::Ready(()) => Poll::Ready(Err(io::Error::new(
                io::ErrorKind::TimedOut,
                "connection idle for longer than listen_policy.idle_timeout_s",
            ))),
            Poll::Pending => Poll::Pending,
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for IdleStream<S> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        match Pin::new(&mut this.inner).poll_read(cx, buf) {
            Poll::Ready(r) => {
                if buf.filled().len() > before {
                    this.touch();
                }
                Poll::Ready(r)
            }
            Poll::Pending => this.poll_idle(cx),
        }
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for IdleStream<S> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        match Pin::new(&mut this.inner).poll_write(cx, buf) {
            Poll::Ready(r) => {
                if matches!(r, Ok(n) if n > 0) {
                    this.touch();
                }
                Poll::Ready(r)
            }
            Poll::Pending => this.poll_idle(cx),
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }
}

/// Open descriptors of this process (Linux: entries of /proc/self/fd, minus the one read_dir uses).
pub fn open_fds() -> Option<u64> {
    let n = std::fs::read_dir("/proc/self/fd").ok()?.count() as u64;
    Some(n.saturating_sub(1))
}

fn nofile_soft_limit() -> Option<u64> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes into the struct we pass and nothing else.
    let rc = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) };
    (rc == 0 && lim.rlim_cur != libc::RLIM_INFINITY).then_some(lim.rlim_cur)
}

/// Raise the soft descriptor limit to the hard one (many distributions start services at 1024
/// soft with a much higher hard limit); the connection caps stay far below either.
pub fn raise_nofile_soft_limit() {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit read and write only the struct we pass.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) == 0 && lim.rlim_cur < lim.rlim_max {
            let was = lim.rlim_cur;
            lim.rlim_cur = lim.rlim_max;
            if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) == 0 {
                tracing::info!(
                    from = was,
                    to = lim.rlim_max,
                    "raised soft RLIMIT_NOFILE to the hard limit"
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    fn echo(policy: ListenPolicy) -> Spec {
        Spec {
            name: "echo",
            policy,
            refusal: b"busy\n",
            handler: Arc::new(|mut c: Conn| {
                Box::pin(async move {
                    let mut b = [0u8; 64];
                    while let Ok(n) = c.stream.read(&mut b).await {
                        if n == 0 || c.stream.write_all(&b[..n]).await.is_err() {
                            break;
                        }
                    }
                })
            }),
        }
    }

    #[tokio::test]
    async fn caps_idle_timeout_and_release() {
        let policy = ListenPolicy {
            max_connections: 2,
            max_connections_per_peer: 2,
            idle_timeout_s: 0.3,
            allow_writes_from: vec![],
            ..ListenPolicy::default()
        };
        let l = listen("127.0.0.1:0".parse().unwrap(), echo(policy))
            .await
            .unwrap();
        let mut a = TcpStream::connect(l.addr).await.unwrap();
        let mut b = TcpStream::connect(l.addr).await.unwrap();
        for s in [&mut a, &mut b] {
            s.write_all(b"x").await.unwrap();
            let mut one = [0u8; 1];
            s.read_exact(&mut one).await.unwrap();
        }
        // The third is refused with the refusal bytes, then closed.
        let mut c = TcpStream::connect(l.addr).await.unwrap();
        let mut got = Vec::new();
        c.read_to_end(&mut got).await.unwrap();
        assert_eq!(got, b"busy\n");
        assert_eq!(l.health.faults()[0].1, crate::fault::FaultKind::Overloaded);
        // Idle: both are closed by the server (read gives EOF or reset), bounded wait.
        let mut one = [0u8; 1];
        let r = tokio::time::timeout(Duration::from_secs(30), a.read(&mut one)).await;
        assert!(matches!(r, Ok(Ok(0) | Err(_))), "{r:?}");
        drop((a, b));
        // Slots released: a new client is served, and that clears the fault.
        let mut served = false;
        for _ in 0..100 {
            let mut d = TcpStream::connect(l.addr).await.unwrap();
            d.write_all(b"y").await.unwrap();
            let mut one = [0u8; 1];
            if matches!(d.read(&mut one).await, Ok(1)) && one == *b"y" {
                served = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        assert!(served);
        assert!(l.health.faults().is_empty(), "{:?}", l.health.faults());
    }

    async fn echoes(s: &mut TcpStream) -> bool {
        let mut one = [0u8; 1];
        s.write_all(b"e").await.is_ok() && matches!(s.read(&mut one).await, Ok(1)) && one == *b"e"
    }

    /// The restart path: a handler that panics while its future is being made ends the accept
    /// loop's task. The supervisor raises `listener_failed`, re-binds the same address and serves
    /// again; a connection admitted before keeps being served across the restart; the next
    /// accepted connection clears the fault.
    #[tokio::test]
    async fn a_failed_accept_loop_is_restarted_with_a_fault_and_keeps_connections() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let calls = Arc::new(AtomicUsize::new(0));
        let inner = echo(ListenPolicy {
            allow_writes_from: vec![],
            ..ListenPolicy::default()
        });
        let counted = Arc::clone(&calls);
        let spec = Spec {
            handler: Arc::new(move |c: Conn| {
                // The second connection's handler panics before its future exists.
                assert!(
                    counted.fetch_add(1, Ordering::SeqCst) != 1,
                    "handler fails once"
                );
                (inner.handler)(c)
            }),
            ..echo(ListenPolicy::default())
        };
        let l = listen("127.0.0.1:0".parse().unwrap(), spec).await.unwrap();
        let mut first = TcpStream::connect(l.addr).await.unwrap();
        assert!(echoes(&mut first).await);
        // The second connection makes the accept loop panic: it is dropped unserved.
        let mut second = TcpStream::connect(l.addr).await.unwrap();
        let mut got = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(30), second.read_to_end(&mut got)).await;
        let failed = |l: &Listening| {
            l.health
                .faults()
                .iter()
                .any(|f| f.1 == crate::fault::FaultKind::ListenerFailed)
        };
        for _ in 0..3000 {
            if l.health.restarts() >= 1 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        assert_eq!(l.health.restarts(), 1);
        // Nothing accepted since: the fault stands.
        assert!(failed(&l), "{:?}", l.health.faults());
        // The connection admitted before the failure is still served.
        assert!(echoes(&mut first).await);
        // A new connection is served by the restarted loop (bounded retries: it re-binds first),
        // and serving clears the fault.
        let mut served = false;
        for _ in 0..300 {
            if let Ok(mut c) = TcpStream::connect(l.addr).await
                && echoes(&mut c).await
            {
                served = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(served, "not served after the restart");
        assert!(!failed(&l), "{:?}", l.health.faults());
    }
}
