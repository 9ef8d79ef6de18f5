//! NMT commands (COB-ID 0x000) and heartbeat (0x700 + node), with a heartbeat monitor that turns a
//! missing heartbeat into [`Health::Stale`]. Times are seconds on the caller's clock.

use crate::Health;
use crate::can::Frame;
use embedded_can::Frame as _;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmtCommand {
    Start,
    Stop,
    EnterPreOperational,
    ResetNode,
    ResetCommunication,
}

impl NmtCommand {
    pub fn code(self) -> u8 {
        match self {
            NmtCommand::Start => 0x01,
            NmtCommand::Stop => 0x02,
            NmtCommand::EnterPreOperational => 0x80,
            NmtCommand::ResetNode => 0x81,
            NmtCommand::ResetCommunication => 0x82,
        }
    }

    pub fn from_code(c: u8) -> Option<Self> {
        Some(match c {
            0x01 => NmtCommand::Start,
            0x02 => NmtCommand::Stop,
            0x80 => NmtCommand::EnterPreOperational,
            0x81 => NmtCommand::ResetNode,
            0x82 => NmtCommand::ResetCommunication,
            _ => return None,
        })
    }
}

/// `node` 0 addresses all nodes.
pub fn encode_nmt(cmd: NmtCommand, node: u8) -> Frame {
    Frame::standard(0x000, &[cmd.code(), node]).expect("2 bytes on id 0 is a valid frame")
}

/// `Some((command, target node))` for an NMT frame, `None` for any other frame.
pub fn decode_nmt(f: &Frame) -> Option<(NmtCommand, u8)> {
    if f.is_extended() || f.is_remote_frame() || f.raw_id() != 0 || f.data().len() != 2 {
        return None;
    }
    Some((NmtCommand::from_code(f.data()[0])?, f.data()[1]))
}

/// Node state as announced in heartbeats (CiA 301 §7.2.8.3.2.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeState {
    BootUp,
    Stopped,
    Operational,
    PreOperational,
}

impl NodeState {
    pub fn code(self) -> u8 {
        match self {
            NodeState::BootUp => 0x00,
            NodeState::Stopped => 0x04,
            NodeState::Operational => 0x05,
            NodeState::PreOperational => 0x7F,
        }
    }

    pub fn from_code(c: u8) -> Option<Self> {
        // Bit 7 is the toggle bit of node guarding; heartbeats send it as 0, so mask it off.
        Some(match c & 0x7F {
            0x00 => NodeState::BootUp,
            0x04 => NodeState::Stopped,
            0x05 => NodeState::Operational,
            0x7F => NodeState::PreOperational,
            _ => return None,
        })
    }
}

pub fn encode_heartbeat(node: u8, state: NodeState) -> Frame {
    Frame::standard(0x700 + u16::from(node & 0x7F), &[state.code()])
        .expect("heartbeat id is at most 0x77F")
}

/// `Some((node, state))` for a heartbeat frame; `None` for other frames or an unknown state byte.
pub fn decode_heartbeat(f: &Frame) -> Option<(u8, NodeState)> {
    let id = f.raw_id();
    if f.is_extended() || f.is_remote_frame() || !(0x701..=0x77F).contains(&id) {
        return None;
    }
    if f.data().len() != 1 {
        return None;
    }
    Some((
        u8::try_from(id - 0x700).ok()?,
        NodeState::from_code(f.data()[0])?,
    ))
}

/// Tracks one node's heartbeat. The node is healthy while heartbeats arrive within `timeout_s` and it
/// reports Operational; otherwise its channels are stale.
#[derive(Debug, Clone)]
pub struct HeartbeatMonitor {
    pub node: u8,
    pub timeout_s: f64,
    last_seen_s: Option<f64>,
    state: Option<NodeState>,
    /// Heartbeats that arrived after a timeout had already been declared.
    pub timeouts: u64,
    timed_out: bool,
}

impl HeartbeatMonitor {
    pub fn new(node: u8, timeout_s: f64) -> Self {
        HeartbeatMonitor {
            node,
            timeout_s,
            last_seen_s: None,
            state: None,
            timeouts: 0,
            timed_out: false,
        }
    }

    /// Feed any frame; returns true if it was this node's heartbeat.
    pub fn handle_frame(&mut self, f: &Frame, now_s: f64) -> bool {
        match decode_heartbeat(f) {
            Some((n, st)) if n == self.node => {
                self.last_seen_s = Some(now_s);
                self.state = Some(st);
                self.timed_out = false;
                true
            }
            _ => false,
        }
    }

    pub fn state(&self) -> Option<NodeState> {
        self.state
    }

    /// From when [`Self::poll`] reports this node `Stale`, given the frames seen so far (s, the
    /// monitor's clock): never heard or not operational: already (−∞ or the heartbeat's time);
    /// operational: when its heartbeat times out.
    pub fn stale_from_s(&self) -> f64 {
        match (self.last_seen_s, self.state) {
            (Some(t), Some(NodeState::Operational)) => t + self.timeout_s,
            (Some(t), _) => t,
            (None, _) => f64::NEG_INFINITY,
        }
    }

    /// Health at `now_s`; counts each transition into timeout once.
    pub fn poll(&mut self, now_s: f64) -> Health {
        let fresh = self.last_seen_s.is_some_and(|t| now_s < t + self.timeout_s);
        if !fresh {
            if !self.timed_out && self.last_seen_s.is_some() {
                self.timeouts += 1;
            }
            self.timed_out = self.last_seen_s.is_some();
            return Health::Stale;
        }
        match self.state {
            Some(NodeState::Operational) => Health::Ok,
            _ => Health::Stale,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nmt_start_wire_form() {
        // Bring-up `000#01NN` (rust-stack.md §6): start node 5.
        let f = encode_nmt(NmtCommand::Start, 5);
        assert_eq!((f.raw_id(), f.data()), (0, &[0x01, 0x05][..]));
        assert_eq!(decode_nmt(&f), Some((NmtCommand::Start, 5)));
        assert_eq!(decode_nmt(&Frame::standard(0, &[0x03, 5]).unwrap()), None);
    }

    #[test]
    fn heartbeat_timeout_goes_stale_and_recovers() {
        let mut m = HeartbeatMonitor::new(3, 0.3);
        assert_eq!(m.poll(0.0), Health::Stale, "never seen");
        assert!(m.handle_frame(&encode_heartbeat(3, NodeState::PreOperational), 0.0));
        assert_eq!(m.poll(0.1), Health::Stale, "pre-operational sends no PDOs");
        assert!(!m.handle_frame(&encode_heartbeat(4, NodeState::Operational), 0.1));
        assert!(m.handle_frame(&encode_heartbeat(3, NodeState::Operational), 0.2));
        assert_eq!(m.poll(0.45), Health::Ok);
        assert_eq!(m.poll(0.55), Health::Stale);
        assert_eq!(m.poll(0.60), Health::Stale);
        assert_eq!(m.timeouts, 1);
        m.handle_frame(&encode_heartbeat(3, NodeState::Operational), 0.7);
        assert_eq!(m.poll(0.7), Health::Ok);
    }

    #[test]
    fn stale_from_is_where_poll_turns_stale() {
        let mut m = HeartbeatMonitor::new(3, 0.3);
        assert_eq!(
            m.stale_from_s(),
            f64::NEG_INFINITY,
            "never heard: stale already"
        );
        m.handle_frame(&encode_heartbeat(3, NodeState::PreOperational), 1.0);
        assert_eq!(
            m.stale_from_s(),
            1.0,
            "not operational: stale from that heartbeat"
        );
        m.handle_frame(&encode_heartbeat(3, NodeState::Operational), 2.0);
        let from = m.stale_from_s();
        assert!((from - 2.3).abs() < 1e-12, "{from}");
        assert_eq!(m.poll(from - 1e-9), Health::Ok);
        assert_eq!(m.poll(from + 1e-9), Health::Stale);
    }
}
