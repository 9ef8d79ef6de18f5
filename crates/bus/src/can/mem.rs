//! In-memory CAN bus (tokio broadcast): every endpoint sees the frames of every other endpoint, never
//! its own, like nodes on one physical bus. For unit tests and single-process simulation.

use super::{CanBus, CanError, Frame};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use tokio::sync::broadcast;

/// The bus itself; cheap to clone, every clone is the same bus.
#[derive(Clone, Debug)]
pub struct MemBus {
    tx: broadcast::Sender<(u64, Frame)>,
    next_id: Arc<AtomicU64>,
}

impl MemBus {
    /// `capacity`: frames an endpoint may fall behind before `recv` reports [`CanError::Overrun`].
    pub fn new(capacity: usize) -> Self {
        let (tx, _) = broadcast::channel(capacity.max(1));
        MemBus {
            tx,
            next_id: Arc::new(AtomicU64::new(0)),
        }
    }

    /// A new node on this bus. It receives frames sent after it was created.
    pub fn endpoint(&self) -> MemEndpoint {
        MemEndpoint {
            id: self.next_id.fetch_add(1, Ordering::Relaxed),
            tx: self.tx.clone(),
            rx: self.tx.subscribe(),
        }
    }
}

impl Default for MemBus {
    fn default() -> Self {
        Self::new(4096)
    }
}

#[derive(Debug)]
pub struct MemEndpoint {
    id: u64,
    tx: broadcast::Sender<(u64, Frame)>,
    rx: broadcast::Receiver<(u64, Frame)>,
}

impl CanBus for MemEndpoint {
    async fn send(&mut self, frame: &Frame) -> Result<(), CanError> {
        // With no other endpoint alive nobody listens; on CAN that is not an error for the sender.
        let _ = self.tx.send((self.id, *frame));
        Ok(())
    }

    /// Cancel-safe.
    async fn recv(&mut self) -> Result<Frame, CanError> {
        loop {
            match self.rx.recv().await {
                Ok((from, f)) if from != self.id => return Ok(f),
                Ok(_) => {}
                Err(broadcast::error::RecvError::Lagged(n)) => return Err(CanError::Overrun(n)),
                Err(broadcast::error::RecvError::Closed) => return Err(CanError::Closed),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn fans_out_to_others_not_self_and_reports_overrun() {
        let bus = MemBus::new(2);
        let (mut a, mut b, mut c) = (bus.endpoint(), bus.endpoint(), bus.endpoint());
        let f = Frame::standard(0x181, &[1, 2, 3, 4]).unwrap();
        a.send(&f).await.unwrap();
        assert_eq!(b.recv().await.unwrap(), f);
        assert_eq!(c.recv().await.unwrap(), f);
        let g = Frame::standard(0x182, &[]).unwrap();
        b.send(&g).await.unwrap();
        assert_eq!(
            a.recv().await.unwrap(),
            g,
            "a skips nothing but its own frames"
        );
        for i in 0..3u8 {
            a.send(&Frame::standard(0x100, &[i]).unwrap())
                .await
                .unwrap();
        }
        // c still has g queued plus 3 more in a queue of 2: it lost frames and is told so.
        assert!(matches!(c.recv().await, Err(CanError::Overrun(_))));
    }
}
