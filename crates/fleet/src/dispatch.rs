//! Many diagnose workers for one fleet host (sans-IO: messages and times are passed in, messages to
//! publish are taken out with [`Dispatcher::poll_transmit`]; the host's MQTT shell is
//! crates/fleet/src/fleet_client.rs, the worker's crates/fleet/src/worker.rs).
//!
//! The broker spreads the work: the host publishes one **job** per machine's newest recording on
//! `retrocomp/diagnose/jobs/<group>/<edge node>` (QoS 1) and the workers share the subscription
//! [`SHARED_JOBS`] (MQTT 5 `$share/…`), so each job reaches one of them. The host is the arbiter,
//! because a broker need not hand a dead member's unacknowledged message to another (MQTT 5 §4.8.2
//! makes that a SHOULD): a worker that wants a job publishes a **claim**, and diagnoses only after
//! the host's **grant**. A job has at most one owner: the first claim wins, later ones are denied.
//! A worker's will (`offline`), or its `online` message naming the jobs it holds after a
//! reconnect, frees its other owned jobs, which are published again; a job nobody claimed within
//! `unclaimed_ms` (a message lost, or stuck behind a busy worker) is published again; a result from
//! anyone but the owner is ignored. So each job's accepted result comes from exactly one worker.
//!
//! An owner alive but stuck (its will never comes) holds its job for at most its **lease**
//! ([`Dispatcher::with_owner_timeout`]): a job not finished within the lease after its grant is
//! taken back (the owner is told with a denied grant, its late result is ignored) and published
//! again, with the lease doubled, so a job that is merely slow is not taken back forever.
//!
//! Times are ms on the caller's clock (the host uses ms since the Unix epoch).

use std::collections::{BTreeMap, VecDeque};

use serde::{Deserialize, Serialize};

use crate::drift::MachineDrift;

/// The workers' shared subscription: one group, so each job goes to one member.
pub const SHARED_JOBS: &str = "$share/retrocomp-diagnose/retrocomp/diagnose/jobs/#";
/// Topic prefixes; each is followed by `/<worker id>` (jobs: `/<group>/<edge node>`).
pub const JOBS: &str = "retrocomp/diagnose/jobs";
pub const CLAIMS: &str = "retrocomp/diagnose/claims";
pub const GRANTS: &str = "retrocomp/diagnose/grants";
pub const RESULTS: &str = "retrocomp/diagnose/results";
pub const WORKERS: &str = "retrocomp/diagnose/workers";

/// The host's subscriptions (claims, results, workers' online/offline).
pub fn host_filters() -> [String; 3] {
    [CLAIMS, RESULTS, WORKERS].map(|p| format!("{p}/+"))
}

/// `prefix/<id>`.
pub fn topic(prefix: &str, id: &str) -> String {
    format!("{prefix}/{id}")
}

/// One machine's newest recording to diagnose against its own model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Job {
    pub job: u64,
    pub group: String,
    pub edge_node: String,
    /// Relative to the collect directory (the workers see the same directory, e.g. a share).
    pub recording: String,
    /// The model file, relative to the models directory.
    pub model: String,
    /// Residual (µm RMS) from which an explained residual is drift (`--drift-um`).
    pub drift_um: f64,
}

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Claim {
    pub job: u64,
    pub worker: String,
}

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Grant {
    pub job: u64,
    pub worker: String,
    pub granted: bool,
}

/// A worker's diagnosis: [`crate::drift::judge`] / [`crate::drift::failed`] without the
/// machine's history (the host adds it, [`crate::drift::with_history`]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JobResult {
    pub job: u64,
    pub worker: String,
    pub drift: MachineDrift,
}

/// A worker's presence on `retrocomp/diagnose/workers/<id>`: `online` on every connect (with the
/// granted jobs it still works on), `offline` as its will.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Presence {
    pub state: String,
    #[serde(default)]
    pub holding: Vec<u64>,
}

/// An accepted result: the job and its owner's diagnosis.
#[derive(Clone, Debug)]
pub struct Finished {
    pub job: Job,
    pub worker: String,
    pub drift: MachineDrift,
}

#[derive(Debug)]
struct Slot {
    job: Job,
    owner: Option<String>,
    /// When it was last published and nobody owned it since, ms.
    sent_ms: u64,
    /// When the current owner was granted it, ms.
    granted_ms: u64,
    /// How long an owner may hold it unfinished, ms (doubles at every take-back).
    lease_ms: u64,
}

impl Slot {
    /// When the owner's lease ends (None: no owner, or no lease: `u64::MAX` is never).
    fn lease_end_ms(&self) -> Option<u64> {
        self.owner
            .as_ref()
            .map(|_| self.granted_ms.saturating_add(self.lease_ms))
            .filter(|end| *end != u64::MAX)
    }
}

/// The host's side: unfinished jobs and their owners. Finished jobs are forgotten; a message
/// about a job it does not know (finished, or from before a restart) is denied or ignored.
#[derive(Debug)]
pub struct Dispatcher {
    jobs: BTreeMap<u64, Slot>,
    next_id: u64,
    unclaimed_ms: u64,
    owner_timeout_ms: u64,
    outbox: VecDeque<(String, Vec<u8>)>,
    finished: VecDeque<Finished>,
    /// Jobs published again (owner gone, or unclaimed in time).
    pub republished: u64,
    /// Claims denied (the job had an owner, or was unknown).
    pub denied: u64,
    /// Results ignored (not from the owner, or an unknown job).
    pub ignored: u64,
    /// Jobs taken back from an owner that did not finish within its lease.
    pub taken_back: u64,
}

fn json<T: Serialize>(v: &T) -> Vec<u8> {
    serde_json::to_vec(v).unwrap_or_default()
}

impl Dispatcher {
    /// `first_id`: the first job id (the host passes its start time so that ids of a restarted
    /// host differ from the last run's); `unclaimed_ms`: publish a job again when nobody claimed
    /// it within this long.
    pub fn new(first_id: u64, unclaimed_ms: u64) -> Self {
        Dispatcher {
            jobs: BTreeMap::new(),
            next_id: first_id,
            unclaimed_ms,
            owner_timeout_ms: u64::MAX,
            outbox: VecDeque::new(),
            finished: VecDeque::new(),
            republished: 0,
            denied: 0,
            ignored: 0,
            taken_back: 0,
        }
    }

    /// An owner may hold a job unfinished for `ms` after its grant (then twice as long after each
    /// take-back of that job). Without it an owner holds its job until its will.
    pub fn with_owner_timeout(mut self, ms: u64) -> Self {
        self.owner_timeout_ms = ms.max(1);
        self
    }

    /// Jobs not finished yet.
    pub fn unfinished(&self) -> usize {
        self.jobs.len()
    }

    /// Queue a job (its id is set here) for publishing; returns the id.
    pub fn submit(&mut self, mut job: Job, now_ms: u64) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        job.job = id;
        self.publish(&job);
        self.jobs.insert(
            id,
            Slot {
                job,
                owner: None,
                sent_ms: now_ms,
                granted_ms: now_ms,
                lease_ms: self.owner_timeout_ms,
            },
        );
        id
    }

    fn publish(&mut self, job: &Job) {
        let t = format!("{JOBS}/{}/{}", job.group, job.edge_node);
        self.outbox.push_back((t, json(job)));
    }

    /// Take one message on the host's subscriptions ([`host_filters`]); others are ignored.
    pub fn handle_message(&mut self, topic: &str, payload: &[u8], now_ms: u64) {
        let Some((prefix, worker)) = topic.rsplit_once('/') else {
            return;
        };
        match prefix {
            CLAIMS => {
                if let Ok(c) = serde_json::from_slice::<Claim>(payload) {
                    self.handle_claim(&c, now_ms);
                }
            }
            RESULTS => {
                if let Ok(r) = serde_json::from_slice::<JobResult>(payload) {
                    self.handle_result(r);
                }
            }
            WORKERS => {
                if let Ok(p) = serde_json::from_slice::<Presence>(payload) {
                    self.handle_presence(worker, &p, now_ms);
                }
            }
            _ => {}
        }
    }

    /// First claim wins; the owner claiming again is granted again (its grant may be lost).
    pub fn handle_claim(&mut self, c: &Claim, now_ms: u64) {
        let granted = match self.jobs.get_mut(&c.job) {
            Some(s) if s.owner.is_none() => {
                s.owner = Some(c.worker.clone());
                s.granted_ms = now_ms;
                true
            }
            Some(s) => s.owner.as_deref() == Some(c.worker.as_str()),
            None => false,
        };
        self.denied += u64::from(!granted);
        let g = Grant {
            job: c.job,
            worker: c.worker.clone(),
            granted,
        };
        self.outbox.push_back((topic(GRANTS, &c.worker), json(&g)));
    }

    /// The owner's result finishes the job; any other is ignored.
    pub fn handle_result(&mut self, r: JobResult) {
        let owned = self
            .jobs
            .get(&r.job)
            .is_some_and(|s| s.owner.as_deref() == Some(r.worker.as_str()));
        if !owned {
            self.ignored += 1;
            return;
        }
        if let Some(s) = self.jobs.remove(&r.job) {
            self.finished.push_back(Finished {
                job: s.job,
                worker: r.worker,
                drift: r.drift,
            });
        }
    }

    /// `offline` (its will): every job it owns is published again. `online`: the jobs it owns
    /// but does not hold (a grant lost across its reconnect) are.
    pub fn handle_presence(&mut self, worker: &str, p: &Presence, now_ms: u64) {
        let keep: &[u64] = if p.state == "online" { &p.holding } else { &[] };
        let freed: Vec<u64> = self
            .jobs
            .iter()
            .filter(|(id, s)| s.owner.as_deref() == Some(worker) && !keep.contains(id))
            .map(|(id, _)| *id)
            .collect();
        for id in freed {
            self.republish(id, now_ms);
        }
    }

    fn republish(&mut self, id: u64, now_ms: u64) {
        let Some(s) = self.jobs.get_mut(&id) else {
            return;
        };
        s.owner = None;
        s.sent_ms = now_ms;
        let job = s.job.clone();
        self.republished += 1;
        self.publish(&job);
    }

    /// The next message to publish (topic, JSON): jobs unclaimed for too long published again,
    /// jobs whose owner's lease ended taken back (a denied grant to it) and published again.
    pub fn poll_transmit(&mut self, now_ms: u64) -> Option<(String, Vec<u8>)> {
        if self.outbox.is_empty() {
            self.take_back_expired(now_ms);
        }
        if self.outbox.is_empty() {
            let late: Vec<u64> = self
                .jobs
                .iter()
                .filter(|(_, s)| {
                    s.owner.is_none() && now_ms >= s.sent_ms.saturating_add(self.unclaimed_ms)
                })
                .map(|(id, _)| *id)
                .collect();
            for id in late {
                self.republish(id, now_ms);
            }
        }
        self.outbox.pop_front()
    }

    fn take_back_expired(&mut self, now_ms: u64) {
        let expired: Vec<(u64, String)> = self
            .jobs
            .iter()
            .filter(|(_, s)| s.lease_end_ms().is_some_and(|end| now_ms >= end))
            .filter_map(|(id, s)| Some((*id, s.owner.clone()?)))
            .collect();
        for (id, owner) in expired {
            tracing::warn!(
                job = id,
                worker = owner,
                "fleet: a worker did not finish its job within its lease: taken back"
            );
            let g = Grant {
                job: id,
                worker: owner.clone(),
                granted: false,
            };
            self.outbox.push_back((topic(GRANTS, &owner), json(&g)));
            if let Some(s) = self.jobs.get_mut(&id) {
                s.lease_ms = s.lease_ms.saturating_mul(2);
            }
            self.taken_back += 1;
            self.republish(id, now_ms);
        }
    }

    /// Put back a message [`Dispatcher::poll_transmit`] gave that could not be sent yet.
    pub fn unsend(&mut self, msg: (String, Vec<u8>)) {
        self.outbox.push_front(msg);
    }

    /// When the next unclaimed job falls due or the next owner's lease ends (ms); None when no
    /// job waits for either.
    pub fn poll_timeout(&self) -> Option<u64> {
        self.jobs
            .values()
            .filter_map(|s| match s.owner {
                Some(_) => s.lease_end_ms(),
                None => Some(s.sent_ms.saturating_add(self.unclaimed_ms)),
            })
            .min()
    }

    /// The next accepted result.
    pub fn poll_finished(&mut self) -> Option<Finished> {
        self.finished.pop_front()
    }
}

#[cfg(test)]
#[path = "dispatch_tests.rs"]
mod tests;
