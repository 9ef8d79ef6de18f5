//! Sans-IO core of the Modbus poller: the read plan, turning each read's outcome into samples with
//! health and counters, and the RTU inter-frame silence (the reconnect backoff is [`crate::Backoff`]).
//!
//! Outcome → health: registers → decoded value (`Ok` / `OutOfRange`); a Modbus exception (the device
//! answered "no") → `DecodeError`, value NaN; a timeout or transport failure (no answer) → `Stale`
//! with the channel's last good value (NaN if none).

use super::regmap::{ReadBlock, RegisterChannel, plan_reads};
use crate::{ChannelId, ChannelTable, Health, Sample};
use tokio_modbus::ExceptionCode;

/// What one read request produced.
#[derive(Debug, Clone, PartialEq)]
pub enum ReadOutcome {
    Registers(Vec<u16>),
    Exception(ExceptionCode),
    Timeout,
    Transport(String),
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PollCounters {
    pub requests: u64,
    pub responses: u64,
    pub exceptions: u64,
    pub timeouts: u64,
    pub transport_errors: u64,
    pub connects: u64,
    pub connect_failures: u64,
    /// Reads that returned the wrong number of registers.
    pub decode_errors: u64,
    pub out_of_range: u64,
}

#[derive(Debug, Clone)]
pub struct PollCore {
    pub channels: Vec<RegisterChannel>,
    pub plan: Vec<ReadBlock>,
    /// Each channel's id, resolved at construction (no name on the per-read path).
    ids: Vec<ChannelId>,
    last_good: Vec<f64>,
    pub counters: PollCounters,
}

impl PollCore {
    /// The poller of `channels`, each resolved in `table` (the gateway's).
    pub fn new(
        channels: Vec<RegisterChannel>,
        table: &mut ChannelTable,
        max_count: u16,
        max_gap: u16,
    ) -> Self {
        let plan = plan_reads(&channels, max_count, max_gap);
        PollCore {
            last_good: vec![f64::NAN; channels.len()],
            ids: channels.iter().map(|c| table.resolve(&c.channel)).collect(),
            channels,
            plan,
            counters: PollCounters::default(),
        }
    }

    /// Samples for block `b` given its outcome at `t_s`.
    pub fn handle_outcome(
        &mut self,
        b: usize,
        outcome: &ReadOutcome,
        t_s: f64,
        out: &mut Vec<Sample>,
    ) {
        let block = &self.plan[b];
        self.counters.requests += 1;
        match outcome {
            ReadOutcome::Registers(words) => {
                self.counters.responses += 1;
                let short = words.len() != usize::from(block.count);
                if short {
                    self.counters.decode_errors += 1;
                }
                for &i in &block.members {
                    let c = &self.channels[i];
                    let from = usize::from(c.address - block.start);
                    let n = usize::from(c.data_type.words());
                    let (value, health) = match words.get(from..from + n) {
                        Some(w) if !short => c.decode(w),
                        _ => (f64::NAN, Health::DecodeError),
                    };
                    match health {
                        Health::Ok => self.last_good[i] = value,
                        Health::OutOfRange => self.counters.out_of_range += 1,
                        _ => {}
                    }
                    out.push(sample(self.ids[i], t_s, value, health));
                }
            }
            ReadOutcome::Exception(_) => {
                self.counters.exceptions += 1;
                for &i in &block.members {
                    out.push(sample(self.ids[i], t_s, f64::NAN, Health::DecodeError));
                }
            }
            ReadOutcome::Timeout | ReadOutcome::Transport(_) => {
                if matches!(outcome, ReadOutcome::Timeout) {
                    self.counters.timeouts += 1;
                } else {
                    self.counters.transport_errors += 1;
                }
                self.stale_block(b, t_s, out);
            }
        }
    }

    /// `Stale` samples for every channel of block `b` (no read was possible).
    pub fn stale_block(&self, b: usize, t_s: f64, out: &mut Vec<Sample>) {
        for &i in &self.plan[b].members {
            out.push(sample(self.ids[i], t_s, self.last_good[i], Health::Stale));
        }
    }
}

fn sample(channel: ChannelId, t_s: f64, value: f64, health: Health) -> Sample {
    Sample {
        channel,
        t_s,
        value,
        health,
    }
}

/// Modbus RTU inter-frame silence t3.5 in seconds: 3.5 characters of 11 bits up to 19200 Bd, a fixed
/// 1.75 ms above (Modbus over serial line spec §2.5.1.1; anchors-compensation.md: 9600 Bd → 4.01 ms).
pub(crate) fn rtu_silence_s(baud: u32) -> f64 {
    if baud > 19_200 {
        1.75e-3
    } else {
        3.5 * 11.0 / f64::from(baud.max(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::{DataType, RegisterTable, WordOrder};

    fn chans() -> Vec<RegisterChannel> {
        (0..3)
            .map(|i| RegisterChannel {
                channel: format!("T{i}_C"),
                kind: RegisterTable::Input,
                address: i,
                data_type: DataType::Int16,
                word_order: WordOrder::HighFirst,
                scale: 0.1,
                offset: 0.0,
                min: Some(-50.0),
                max: Some(150.0),
            })
            .collect()
    }

    #[test]
    fn outcomes_map_to_health() {
        let mut core = PollCore::new(chans(), &mut ChannelTable::default(), 125, 0);
        assert_eq!(core.plan.len(), 1);
        let mut out = Vec::new();
        core.handle_outcome(
            0,
            &ReadOutcome::Registers(vec![215, 2000, 0xFFF6]),
            1.0,
            &mut out,
        );
        let h: Vec<_> = out.iter().map(|s| (s.health, s.value)).collect();
        assert_eq!(h[0], (Health::Ok, 21.5));
        assert_eq!(h[1].0, Health::OutOfRange);
        assert_eq!(h[2], (Health::Ok, -1.0));
        out.clear();
        core.handle_outcome(0, &ReadOutcome::Timeout, 2.0, &mut out);
        assert!(out.iter().all(|s| s.health == Health::Stale));
        assert_eq!(out[0].value, 21.5, "stale keeps the last good value");
        assert!(out[1].value.is_nan(), "never good → NaN");
        out.clear();
        core.handle_outcome(
            0,
            &ReadOutcome::Exception(ExceptionCode::IllegalDataAddress),
            3.0,
            &mut out,
        );
        assert!(
            out.iter()
                .all(|s| s.health == Health::DecodeError && s.value.is_nan())
        );
        out.clear();
        core.handle_outcome(0, &ReadOutcome::Registers(vec![1]), 4.0, &mut out);
        assert!(out.iter().all(|s| s.health == Health::DecodeError));
        let c = core.counters;
        assert_eq!(
            (
                c.requests,
                c.responses,
                c.timeouts,
                c.exceptions,
                c.decode_errors
            ),
            (4, 2, 1, 1, 1)
        );
    }

    #[test]
    fn t35_values() {
        // 9600 Bd: 3.5 × 11 / 9600 = 4.01 ms (anchors-compensation.md, JUMO manual)
        assert!((rtu_silence_s(9600) - 4.0104e-3).abs() < 1e-6);
        assert!((rtu_silence_s(19200) - 2.005e-3).abs() < 1e-6);
        assert_eq!(rtu_silence_s(115_200), 1.75e-3);
    }
}
