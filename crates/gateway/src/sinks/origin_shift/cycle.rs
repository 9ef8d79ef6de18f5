//! One origin-shift write cycle as a sans-IO state machine: it says which Modbus request to make next
//! and is told the reply; the async shell (`client.rs`) does the I/O.
//!
//! Sequence: write each value block (one FC16 each) → [toggle the strobe, poll the ack until it equals
//! the strobe or `timeout_ms` passes] → [read every block back and compare] → done.
//! Time is seconds on the caller's clock. Any error ends the cycle with an [`Outcome`] that says where.
//! Requests and replies carry their words inline ([`Words`]): a cycle allocates nothing but the
//! text of a failure.

use super::map::{RegisterMap, Words, WriteBlock};

#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// FC16 write of contiguous words (already allow-list checked).
    Write(WriteBlock),
    /// FC03 read; `not_before_s` paces ack polling.
    Read {
        address: u16,
        count: u16,
        not_before_s: f64,
    },
    Done(Outcome),
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    Ok,
    /// The transport or the controller failed a request (exception, timeout, disconnect).
    RequestFailed {
        step: &'static str,
        address: u16,
        reason: String,
    },
    AckTimeout {
        strobe: u16,
        last_ack: Option<u16>,
    },
    ReadbackMismatch {
        address: u16,
        wrote: Vec<u16>,
        read: Vec<u16>,
    },
}

#[derive(Clone, Debug)]
pub enum Reply {
    Written,
    /// The words read (inline up to 8: no allocation for a sink's reads).
    Read(Words),
    Failed(String),
}

#[derive(Clone, Debug)]
enum State {
    Writing(usize),
    Strobing,
    WaitingAck { deadline_s: f64 },
    Verifying(usize),
    Finished,
}

#[derive(Clone, Debug)]
pub struct WriteCycle {
    blocks: Vec<WriteBlock>,
    handshake: Option<(u16, u16, f64, f64)>, // strobe, ack, timeout_s, poll_s
    verify: bool,
    strobe_value: u16,
    state: State,
}

impl WriteCycle {
    /// Start a cycle for already-encoded blocks. `strobe_value` is the value to write to the strobe
    /// (the caller toggles it 0/1 between cycles: [`WriteCycle::next_strobe`]).
    pub fn start(map: &RegisterMap, blocks: Vec<WriteBlock>, strobe_value: u16) -> (Self, Action) {
        Self::start_at(map, blocks, strobe_value, 0.0)
    }

    /// [`WriteCycle::start`] at time `now_s` (matters when there is nothing to write or strobe).
    pub fn start_at(
        map: &RegisterMap,
        blocks: Vec<WriteBlock>,
        strobe_value: u16,
        now_s: f64,
    ) -> (Self, Action) {
        let mut c = Self {
            blocks,
            handshake: map.handshake.as_ref().map(|h| {
                (
                    h.strobe_address,
                    h.ack_address,
                    h.timeout_ms as f64 / 1e3,
                    h.poll_ms as f64 / 1e3,
                )
            }),
            verify: map.verify_readback,
            strobe_value,
            state: State::Writing(0),
        };
        let a = c.after_writes_from(0, now_s);
        (c, a)
    }

    pub fn next_strobe(previous: u16) -> u16 {
        if previous == 0 { 1 } else { 0 }
    }

    pub fn strobe_value(&self) -> u16 {
        self.strobe_value
    }

    /// The blocks back, for the next cycle to reuse (their buffers: no allocation per write).
    pub fn into_blocks(self) -> Vec<WriteBlock> {
        self.blocks
    }

    fn after_writes_from(&mut self, i: usize, now_s: f64) -> Action {
        if let Some(b) = self.blocks.get(i) {
            self.state = State::Writing(i);
            return Action::Write(b.clone());
        }
        if let Some((strobe, _, _, _)) = self.handshake {
            self.state = State::Strobing;
            return Action::Write(WriteBlock {
                address: strobe,
                words: Words::from_slice(&[self.strobe_value]),
            });
        }
        self.verify_from(0, now_s)
    }

    fn verify_from(&mut self, i: usize, now_s: f64) -> Action {
        match self.blocks.get(i) {
            Some(b) if self.verify => {
                self.state = State::Verifying(i);
                Action::Read {
                    address: b.address,
                    count: u16::try_from(b.words.len())
                        .expect("a block is at most 123 words (map.rs)"),
                    not_before_s: now_s,
                }
            }
            _ => self.finish(Outcome::Ok),
        }
    }

    fn finish(&mut self, o: Outcome) -> Action {
        self.state = State::Finished;
        Action::Done(o)
    }

    /// Feed the reply to the last action, at time `now_s`; get the next action.
    pub fn handle_reply(&mut self, reply: Reply, now_s: f64) -> Action {
        let state = self.state.clone();
        match (state, reply) {
            (State::Finished, _) => Action::Done(Outcome::Ok),
            (State::Writing(i), Reply::Written) => self.after_writes_from(i + 1, now_s),
            (State::Strobing, Reply::Written) => {
                let (_, ack, timeout_s, _) = self.handshake.expect("strobing implies a handshake");
                self.state = State::WaitingAck {
                    deadline_s: now_s + timeout_s,
                };
                Action::Read {
                    address: ack,
                    count: 1,
                    not_before_s: now_s,
                }
            }
            (State::WaitingAck { deadline_s, .. }, Reply::Read(words)) => {
                let (_, ack, _, poll_s) = self.handshake.expect("waiting implies a handshake");
                let last = words.first().copied();
                if last == Some(self.strobe_value) {
                    return self.verify_from(0, now_s);
                }
                if now_s >= deadline_s {
                    return self.finish(Outcome::AckTimeout {
                        strobe: self.strobe_value,
                        last_ack: last,
                    });
                }
                self.state = State::WaitingAck { deadline_s };
                Action::Read {
                    address: ack,
                    count: 1,
                    not_before_s: (now_s + poll_s).min(deadline_s),
                }
            }
            (State::Verifying(i), Reply::Read(words)) => {
                let b = &self.blocks[i];
                if words != b.words {
                    let o = Outcome::ReadbackMismatch {
                        address: b.address,
                        wrote: b.words.to_vec(),
                        read: words.to_vec(),
                    };
                    return self.finish(o);
                }
                self.verify_from(i + 1, now_s)
            }
            (s, Reply::Failed(reason)) => {
                let (step, address) = self.where_in(&s);
                self.finish(Outcome::RequestFailed {
                    step,
                    address,
                    reason,
                })
            }
            (s, r) => {
                let (step, address) = self.where_in(&s);
                self.finish(Outcome::RequestFailed {
                    step,
                    address,
                    reason: format!("unexpected reply {r:?}"),
                })
            }
        }
    }

    fn where_in(&self, s: &State) -> (&'static str, u16) {
        match s {
            State::Writing(i) => ("write", self.blocks[*i].address),
            State::Strobing => ("strobe", self.handshake.map_or(0, |h| h.0)),
            State::WaitingAck { .. } => ("ack", self.handshake.map_or(0, |h| h.1)),
            State::Verifying(i) => ("readback", self.blocks[*i].address),
            State::Finished => ("done", 0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sinks::origin_shift::map::RegisterMap;
    use retrocomp_model::Axis;

    fn map(handshake: bool) -> RegisterMap {
        let mut s = String::from(
            "[[axis]]\naxis = \"x\"\naddress = 10\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n\
             [[axis]]\naxis = \"y\"\naddress = 20\nkind = \"int16\"\nlsb_um = 1.0\nsign = 1\n",
        );
        if handshake {
            s.push_str("[handshake]\nstrobe_address = 30\nack_address = 31\ntimeout_ms = 100\npoll_ms = 10\n");
        }
        toml::from_str(&s).unwrap()
    }

    #[test]
    fn full_cycle_with_handshake_and_readback() {
        let m = map(true);
        let blocks = m.encode(&[(Axis::X, 1.5), (Axis::Y, -2.0)]).unwrap();
        let (mut c, a) = WriteCycle::start(&m, blocks.clone(), 1);
        assert_eq!(a, Action::Write(blocks[0].clone()));
        assert_eq!(
            c.handle_reply(Reply::Written, 0.0),
            Action::Write(blocks[1].clone())
        );
        assert_eq!(
            c.handle_reply(Reply::Written, 0.0),
            Action::Write(WriteBlock {
                address: 30,
                words: vec![1].into()
            })
        );
        assert_eq!(
            c.handle_reply(Reply::Written, 0.0),
            Action::Read {
                address: 31,
                count: 1,
                not_before_s: 0.0
            }
        );
        // Controller not yet acked: poll again 10 ms later.
        assert_eq!(
            c.handle_reply(Reply::Read(vec![0].into()), 0.001),
            Action::Read {
                address: 31,
                count: 1,
                not_before_s: 0.011
            }
        );
        assert_eq!(
            c.handle_reply(Reply::Read(vec![1].into()), 0.011),
            Action::Read {
                address: 10,
                count: 2,
                not_before_s: 0.011
            }
        );
        assert_eq!(
            c.handle_reply(Reply::Read(blocks[0].words.clone()), 0.012),
            Action::Read {
                address: 20,
                count: 1,
                not_before_s: 0.012
            }
        );
        assert_eq!(
            c.handle_reply(Reply::Read(blocks[1].words.clone()), 0.013),
            Action::Done(Outcome::Ok)
        );
    }

    #[test]
    fn ack_timeout_and_readback_mismatch_are_reported() {
        let m = map(true);
        let blocks = m.encode(&[(Axis::Y, 3.0)]).unwrap();
        let (mut c, _) = WriteCycle::start(&m, blocks.clone(), 0);
        c.handle_reply(Reply::Written, 0.0);
        c.handle_reply(Reply::Written, 0.0);
        let mut t = 0.0;
        let out = loop {
            t += 0.01;
            if let Action::Done(o) = c.handle_reply(Reply::Read(vec![1].into()), t) {
                break o;
            }
        };
        assert!(matches!(
            out,
            Outcome::AckTimeout {
                strobe: 0,
                last_ack: Some(1)
            }
        ));
        assert!((0.1..0.12).contains(&t), "timed out at {t}");

        let m = map(false);
        let (mut c, _) = WriteCycle::start(&m, blocks, 0);
        assert!(matches!(
            c.handle_reply(Reply::Written, 0.0),
            Action::Read { address: 20, .. }
        ));
        assert!(matches!(
            c.handle_reply(Reply::Read(vec![4].into()), 0.0),
            Action::Done(Outcome::ReadbackMismatch { address: 20, .. })
        ));
        let (mut c, _) = WriteCycle::start(&m, m.encode(&[(Axis::Y, 3.0)]).unwrap(), 0);
        assert!(matches!(
            c.handle_reply(Reply::Failed("timeout".into()), 0.0),
            Action::Done(Outcome::RequestFailed {
                step: "write",
                address: 20,
                ..
            })
        ));
    }
}
