//! A diagnose worker's MQTT 5 shell (`retrocomp fleet-worker`; the protocol is
//! crates/fleet/src/dispatch.rs): a member of the shared subscription [`SHARED_JOBS`], with the
//! will `retrocomp/diagnose/workers/<id>` = offline and an `online` message (with the granted job
//! it still works on) after every connect. Jobs are taken one at a time: claim, wait for the
//! host's grant (the claim is sent again every `claim_retry` while no answer comes: a grant can be
//! lost across a reconnect), diagnose off the MQTT loop, publish the result. Jobs that arrive while
//! busy wait in order; the host publishes them again elsewhere if they wait too long, and a late
//! claim for them is simply denied.
//!
//! A job's paths are relative to the worker's collect and models directories (the host's, seen
//! through a share); a path that leaves them is refused. Units: the diagnosis in µm, durations ms.

use std::collections::VecDeque;
use std::path::{Component, Path, PathBuf};
use std::time::{Duration, Instant};

use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::{LastWill, Packet};
use rumqttc::v5::{AsyncClient, Event, MqttOptions};
use serde::Serialize;

use crate::dispatch::{
    CLAIMS, Claim, GRANTS, Grant, JOBS, Job, JobResult, Presence, RESULTS, SHARED_JOBS, WORKERS,
    topic,
};
use crate::drift::{self, DriftState, MachineDrift};
use retrocomp_model::error::Chain;

/// Why a worker cannot run.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error("--broker {0}: expected HOST:PORT")]
    Broker(String),
    /// The request could not be queued (boxed: the request it carries is large).
    #[error(transparent)]
    Client(Box<rumqttc::v5::ClientError>),
    #[error("diagnose task: {0}")]
    Task(#[from] tokio::task::JoinError),
}

impl From<rumqttc::v5::ClientError> for WorkerError {
    fn from(e: rumqttc::v5::ClientError) -> Self {
        WorkerError::Client(Box::new(e))
    }
}

#[derive(Clone, Debug)]
pub struct WorkerConfig {
    /// HOST:PORT.
    pub broker: String,
    /// This worker's name (unique among the workers: it is its MQTT client id's tail).
    pub id: String,
    pub collect_dir: PathBuf,
    pub models: PathBuf,
    /// Wait this long after a grant before diagnosing (tests kill a worker holding a job).
    pub hold_after_grant: Duration,
    /// Send a claim again when no grant or denial came within this long.
    pub claim_retry: Duration,
}

/// One job this worker finished (its stdout line).
#[derive(Clone, Debug, Serialize)]
pub struct Done {
    pub job: u64,
    pub worker: String,
    pub group: String,
    pub edge_node: String,
    pub recording: String,
    pub state: DriftState,
    pub rms_um: f64,
    /// From the grant to the result, ms.
    pub took_ms: u64,
}

/// What the worker tells its caller.
#[derive(Debug)]
pub enum WorkerEvent<'a> {
    /// Subscribed (after every connect).
    Subscribed,
    /// Granted a job; it diagnoses it next (after `hold_after_grant`).
    Granted(&'a Job),
    Done(&'a Done),
    /// The link failed (the next poll reconnects).
    Link(String),
}

/// `rel` under `base`, when it is a plain relative path (no root, no `..`).
fn inside(base: &Path, rel: &str) -> Option<PathBuf> {
    let p = Path::new(rel);
    p.components()
        .all(|c| matches!(c, Component::Normal(_)))
        .then(|| base.join(p))
}

/// The diagnosis the in-process fleet makes ([`drift::judge`] / [`drift::failed`]), without
/// the machine's history (the host has it).
pub fn diagnose_job(collect: &Path, models: &Path, job: &Job) -> MachineDrift {
    let (Some(rec), Some(model)) = (inside(collect, &job.recording), inside(models, &job.model))
    else {
        return drift::failed(
            Path::new(&job.recording),
            Path::new(&job.model),
            "a job path outside the collect or models directory".into(),
            None,
        );
    };
    match drift::diagnose_against(&rec, &model) {
        Ok(r) => drift::judge(&r, &rec, &model, job.drift_um, None),
        Err(e) => drift::failed(&rec, &model, Chain(&e).to_string(), None),
    }
}

type Work = tokio::task::JoinHandle<Result<MachineDrift, tokio::task::JoinError>>;

/// A worker's state around its MQTT client: jobs waiting, the one claimed, the one granted.
struct Shell {
    cfg: WorkerConfig,
    client: AsyncClient,
    grants: String,
    queue: VecDeque<Job>,
    /// The job claimed, and when the claim was last sent.
    waiting: Option<(Job, Instant)>,
    /// The job granted, its diagnosis, and when it was granted.
    work: Option<(Job, Work, Instant)>,
    subacks: u32,
}

impl Shell {
    fn publish(&self, prefix: &str, payload: &impl Serialize) -> Result<(), WorkerError> {
        let p = serde_json::to_vec(payload).unwrap_or_default();
        let t = topic(prefix, &self.cfg.id);
        Ok(self.client.try_publish(t, QoS::AtLeastOnce, false, p)?)
    }

    /// Claim the waiting job (again), or the next queued one when idle.
    fn claim(&mut self, again: bool) -> Result<(), WorkerError> {
        if self.waiting.is_none() && self.work.is_none() {
            self.waiting = self.queue.pop_front().map(|j| (j, Instant::now()));
        } else if !again {
            return Ok(());
        }
        if let Some((j, t)) = &mut self.waiting {
            *t = Instant::now();
            let c = Claim {
                job: j.job,
                worker: self.cfg.id.clone(),
            };
            self.publish(CLAIMS, &c)?;
        }
        Ok(())
    }

    fn knows(&self, id: u64) -> bool {
        self.queue.iter().any(|q| q.job == id)
            || self.waiting.as_ref().is_some_and(|(w, _)| w.job == id)
            || self.work.as_ref().is_some_and(|(w, _, _)| w.job == id)
    }

    /// One MQTT event.
    fn handle(
        &mut self,
        p: Packet,
        on: &mut impl FnMut(WorkerEvent<'_>),
    ) -> Result<(), WorkerError> {
        match p {
            Packet::ConnAck(_) => {
                self.subacks = 0;
                self.client.try_subscribe(SHARED_JOBS, QoS::AtLeastOnce)?;
                self.client
                    .try_subscribe(self.grants.clone(), QoS::AtLeastOnce)?;
            }
            Packet::SubAck(_) => {
                self.subacks += 1;
                if self.subacks == 2 {
                    let p = Presence {
                        state: "online".into(),
                        holding: self.work.iter().map(|(j, _, _)| j.job).collect(),
                    };
                    self.publish(WORKERS, &p)?;
                    // A claim sent before the reconnect may be lost with its answer.
                    self.claim(true)?;
                    on(WorkerEvent::Subscribed);
                }
            }
            Packet::Publish(p) => {
                let t = String::from_utf8_lossy(&p.topic);
                if t.starts_with(JOBS) {
                    if let Ok(j) = serde_json::from_slice::<Job>(&p.payload)
                        && !self.knows(j.job)
                    {
                        self.queue.push_back(j);
                    }
                } else if t == self.grants
                    && let Ok(g) = serde_json::from_slice::<Grant>(&p.payload)
                    && self.waiting.as_ref().is_some_and(|(j, _)| j.job == g.job)
                    && let Some((j, _)) = self.waiting.take()
                    && g.granted
                {
                    on(WorkerEvent::Granted(&j));
                    self.start(j);
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn start(&mut self, j: Job) {
        let (c, m) = (self.cfg.collect_dir.clone(), self.cfg.models.clone());
        let (job, hold) = (j.clone(), self.cfg.hold_after_grant);
        let h = tokio::spawn(async move {
            tokio::time::sleep(hold).await;
            // diagnose is CPU work: off the MQTT loop.
            tokio::task::spawn_blocking(move || diagnose_job(&c, &m, &job)).await
        });
        self.work = Some((j, h, Instant::now()));
    }

    /// The granted job's diagnosis is in: publish it.
    fn finish(
        &mut self,
        d: MachineDrift,
        on: &mut impl FnMut(WorkerEvent<'_>),
    ) -> Result<(), WorkerError> {
        let Some((j, _, since)) = self.work.take() else {
            return Ok(());
        };
        let done = Done {
            job: j.job,
            worker: self.cfg.id.clone(),
            group: j.group,
            edge_node: j.edge_node,
            recording: j.recording,
            state: d.state,
            rms_um: d.rms_um,
            took_ms: u64::try_from(since.elapsed().as_millis()).unwrap_or(u64::MAX),
        };
        let r = JobResult {
            job: j.job,
            worker: self.cfg.id.clone(),
            drift: d,
        };
        self.publish(RESULTS, &r)?;
        on(WorkerEvent::Done(&done));
        Ok(())
    }
}

/// Run until the process ends; `on` sees every event.
pub async fn run(
    cfg: WorkerConfig,
    mut on: impl FnMut(WorkerEvent<'_>),
) -> Result<(), WorkerError> {
    let (host, port) = crate::fleet_client::host_port(&cfg.broker)
        .ok_or_else(|| WorkerError::Broker(cfg.broker.clone()))?;
    let mut o = MqttOptions::new(format!("retrocomp-worker-{}", cfg.id), host, port);
    o.set_keep_alive(Duration::from_secs(10));
    o.set_max_packet_size(Some(1 << 20));
    let offline = Presence {
        state: "offline".into(),
        holding: vec![],
    };
    let will = serde_json::to_vec(&offline).unwrap_or_default();
    o.set_last_will(LastWill::new(
        topic(WORKERS, &cfg.id),
        will,
        QoS::AtLeastOnce,
        false,
        None,
    ));
    let (client, mut events) = AsyncClient::new(o, 64);
    let mut w = Shell {
        grants: topic(GRANTS, &cfg.id),
        cfg,
        client,
        queue: VecDeque::new(),
        waiting: None,
        work: None,
        subacks: 0,
    };
    loop {
        w.claim(false)?;
        let retry = w
            .waiting
            .as_ref()
            .map(|(_, t)| (*t + w.cfg.claim_retry).saturating_duration_since(Instant::now()));
        tokio::select! {
            ev = events.poll() => match ev {
                Ok(Event::Incoming(p)) => w.handle(p, &mut on)?,
                Ok(Event::Outgoing(_)) => {}
                Err(e) => {
                    on(WorkerEvent::Link(e.to_string()));
                    tokio::time::sleep(Duration::from_millis(500)).await;
                }
            },
            _ = tokio::time::sleep(retry.unwrap_or_default()), if retry.is_some() => w.claim(true)?,
            r = async { (&mut w.work.as_mut().expect("guarded").1).await }, if w.work.is_some() => {
                w.finish(r??, &mut on)?;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_path_that_leaves_its_directory_is_refused() {
        let base = Path::new("/srv/fleet");
        assert_eq!(
            inside(base, "shop/m1/w48.csv"),
            Some(PathBuf::from("/srv/fleet/shop/m1/w48.csv"))
        );
        for bad in ["../etc/passwd", "/etc/passwd", "shop/../../x.csv", "./x"] {
            assert_eq!(inside(base, bad), None, "{bad}");
        }
        let j = Job {
            job: 1,
            group: "g".into(),
            edge_node: "n".into(),
            recording: "../x.csv".into(),
            model: "n.toml".into(),
            drift_um: 2.0,
        };
        let d = diagnose_job(base, base, &j);
        assert_eq!(d.state, DriftState::Error);
    }
}
