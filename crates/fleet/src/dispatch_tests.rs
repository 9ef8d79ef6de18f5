//! The arbiter in virtual time (ms): claims and grants, owners dying, lost jobs, late results, and
//! a random interleaving of all of them.

use super::*;
use crate::drift::{DriftState, MachineDrift};

const T: u64 = 5000;

fn job(edge: &str) -> Job {
    Job {
        job: 0,
        group: "shop".into(),
        edge_node: edge.into(),
        recording: format!("shop/{edge}/w48.csv"),
        model: format!("{edge}.toml"),
        drift_um: 2.0,
    }
}

fn drift() -> MachineDrift {
    MachineDrift {
        state: DriftState::Ok,
        recording: "r".into(),
        model: "m".into(),
        rms_um: 0.3,
        baseline_rms_um: 0.3,
        verdict: "none".into(),
        finding: None,
        diagnoses: 1,
        error: None,
    }
}

fn claim(d: &mut Dispatcher, id: u64, w: &str, now: u64) -> bool {
    let c = Claim {
        job: id,
        worker: w.into(),
    };
    d.handle_message(&topic(CLAIMS, w), &serde_json::to_vec(&c).unwrap(), now);
    grants(d, now)
        .into_iter()
        .any(|g| g.job == id && g.worker == w && g.granted)
}

fn grants(d: &mut Dispatcher, now: u64) -> Vec<Grant> {
    let mut out = vec![];
    while let Some((t, p)) = d.poll_transmit(now) {
        if t.starts_with(GRANTS) {
            let g: Grant = serde_json::from_slice(&p).unwrap();
            assert_eq!(t, topic(GRANTS, &g.worker));
            out.push(g);
        }
    }
    out
}

fn jobs(d: &mut Dispatcher, now: u64) -> Vec<Job> {
    let mut out = vec![];
    while let Some((t, p)) = d.poll_transmit(now) {
        let j: Job = serde_json::from_slice(&p).unwrap();
        assert_eq!(t, format!("{JOBS}/{}/{}", j.group, j.edge_node));
        out.push(j);
    }
    out
}

fn result(d: &mut Dispatcher, id: u64, w: &str) {
    let r = JobResult {
        job: id,
        worker: w.into(),
        drift: drift(),
    };
    d.handle_message(&topic(RESULTS, w), &serde_json::to_vec(&r).unwrap(), 0);
}

fn offline(d: &mut Dispatcher, w: &str, now: u64) {
    d.handle_message(&topic(WORKERS, w), br#"{"state":"offline"}"#, now);
}

#[test]
fn the_first_claim_is_granted_a_second_denied_and_the_owners_result_finishes_it() {
    let mut d = Dispatcher::new(100, T);
    let id = d.submit(job("m1"), 0);
    assert_eq!(id, 100);
    assert_eq!(jobs(&mut d, 0).len(), 1);
    assert!(claim(&mut d, id, "w1", 10));
    assert!(!claim(&mut d, id, "w2", 11), "a second claim is denied");
    assert!(
        claim(&mut d, id, "w1", 12),
        "the owner again: granted again"
    );
    assert_eq!(d.denied, 1);
    result(&mut d, id, "w2");
    assert!(d.poll_finished().is_none(), "not the owner's");
    assert_eq!(d.ignored, 1);
    result(&mut d, id, "w1");
    let f = d.poll_finished().unwrap();
    assert_eq!((f.worker.as_str(), f.job.edge_node.as_str()), ("w1", "m1"));
    assert_eq!(d.unfinished(), 0);
    assert!(
        !claim(&mut d, id, "w3", 13),
        "a finished job is not claimed again"
    );
    result(&mut d, id, "w1");
    assert!(d.poll_finished().is_none(), "a duplicate result is ignored");
    assert_eq!(d.poll_timeout(), None);
}

#[test]
fn an_owner_dies_its_job_goes_out_again_and_its_late_result_is_ignored() {
    let mut d = Dispatcher::new(1, T);
    let a = d.submit(job("m1"), 0);
    let b = d.submit(job("m2"), 0);
    jobs(&mut d, 0);
    assert!(claim(&mut d, a, "w1", 1));
    assert!(claim(&mut d, b, "w2", 1));
    offline(&mut d, "w1", 100);
    let again = jobs(&mut d, 100);
    assert_eq!(again.len(), 1, "only the dead worker's job");
    assert_eq!((again[0].job, again[0].edge_node.as_str()), (a, "m1"));
    assert_eq!(d.republished, 1);
    assert!(claim(&mut d, a, "w3", 101), "taken by another");
    result(&mut d, a, "w1");
    assert!(d.poll_finished().is_none(), "the dead owner's late result");
    result(&mut d, a, "w3");
    result(&mut d, b, "w2");
    let by: Vec<_> = std::iter::from_fn(|| d.poll_finished())
        .map(|f| (f.job.job, f.worker))
        .collect();
    assert_eq!(by, vec![(a, "w3".to_string()), (b, "w2".to_string())]);
}

#[test]
fn an_unclaimed_job_goes_out_again_after_the_timeout_and_not_before() {
    let mut d = Dispatcher::new(1, T);
    let a = d.submit(job("m1"), 1000);
    assert_eq!(jobs(&mut d, 1000).len(), 1);
    assert_eq!(d.poll_timeout(), Some(1000 + T));
    assert!(jobs(&mut d, 1000 + T - 1).is_empty());
    assert_eq!(jobs(&mut d, 1000 + T).len(), 1, "lost: published again");
    assert_eq!(d.poll_timeout(), Some(1000 + 2 * T));
    assert!(claim(&mut d, a, "w1", 1000 + T + 1));
    assert_eq!(d.poll_timeout(), None, "owned: no timeout");
    assert!(jobs(&mut d, 1000 + 10 * T).is_empty());
}

#[test]
fn a_stuck_owner_loses_its_job_at_the_end_of_its_lease_and_the_lease_doubles() {
    const LEASE: u64 = 60_000;
    let mut d = Dispatcher::new(1, T).with_owner_timeout(LEASE);
    let a = d.submit(job("m1"), 0);
    jobs(&mut d, 0);
    assert!(claim(&mut d, a, "w1", 10));
    assert_eq!(d.poll_timeout(), Some(10 + LEASE), "the owner's lease");
    assert!(jobs(&mut d, 10 + LEASE - 1).is_empty(), "not before");
    // w1 is alive (no will) but never finishes: at the lease's end it is told and the job goes out.
    let mut out = vec![];
    while let Some(m) = d.poll_transmit(10 + LEASE) {
        out.push(m);
    }
    let denied = Grant {
        job: a,
        worker: "w1".into(),
        granted: false,
    };
    assert_eq!(
        out[0],
        (topic(GRANTS, "w1"), serde_json::to_vec(&denied).unwrap())
    );
    assert_eq!(out.len(), 2, "{out:?}");
    assert!(out[1].0.starts_with(JOBS));
    assert_eq!((d.taken_back, d.republished), (1, 1));
    // The next owner holds it twice as long; the stuck one's late result is not accepted.
    let t2 = 20 + LEASE;
    assert!(claim(&mut d, a, "w2", t2));
    assert_eq!(d.poll_timeout(), Some(t2 + 2 * LEASE));
    assert!(
        jobs(&mut d, t2 + 2 * LEASE - 1).is_empty(),
        "a slow job is not taken back early"
    );
    result(&mut d, a, "w1");
    assert!(d.poll_finished().is_none());
    result(&mut d, a, "w2");
    assert_eq!(d.poll_finished().map(|f| f.worker).as_deref(), Some("w2"));
    assert_eq!(d.poll_timeout(), None);
}

#[test]
fn a_reconnected_worker_keeps_what_it_holds_and_frees_the_rest() {
    let mut d = Dispatcher::new(1, T);
    let a = d.submit(job("m1"), 0);
    let b = d.submit(job("m2"), 0);
    jobs(&mut d, 0);
    assert!(claim(&mut d, a, "w1", 1));
    assert!(claim(&mut d, b, "w1", 1));
    let p = Presence {
        state: "online".into(),
        holding: vec![a],
    };
    d.handle_message(&topic(WORKERS, "w1"), &serde_json::to_vec(&p).unwrap(), 2);
    let again = jobs(&mut d, 2);
    assert_eq!(again.iter().map(|j| j.job).collect::<Vec<_>>(), vec![b]);
    assert!(claim(&mut d, a, "w1", 3), "still its own");
}

/// A tiny deterministic generator (no dependency): xorshift64*.
struct Rng(u64);
impl Rng {
    fn below(&mut self, n: usize) -> usize {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 33;
        usize::try_from(x).unwrap_or(0) % n
    }
}

/// A worker of the simulation: its delivered messages, in order.
#[derive(Default)]
struct SimWorker {
    alive: bool,
    inbox: VecDeque<(String, Vec<u8>)>,
    /// The job it claimed and waits for, and the one granted (it diagnoses it).
    waiting: Option<u64>,
    granted: Option<u64>,
}

/// Random interleavings of deliveries (a job to one live member, as a shared subscription does),
/// lost jobs, claims, grants, results and workers killed (their will) at any point: every job
/// finishes once (by its owner: the dispatcher takes no other result), and no two live workers ever hold a grant for the same job.
#[test]
fn every_job_is_finished_exactly_once_across_random_interleavings() {
    // Over all seeds: owners were killed (their will) or stuck (no will, never finishing), jobs
    // lost and published again, claims denied, stuck owners' jobs taken back at their lease's end.
    let (mut all_kills, mut all_republished, mut all_denied, mut all_taken_back) = (0, 0, 0, 0);
    for seed in 1..=300u64 {
        let mut rng = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
        // A lease far beyond a live worker's time on a job (a few s here): only stuck owners hit it.
        let mut d = Dispatcher::new(1, T).with_owner_timeout(200_000);
        let mut ws: Vec<SimWorker> = (0..4)
            .map(|_| SimWorker {
                alive: true,
                ..Default::default()
            })
            .collect();
        let n_jobs = 8;
        for i in 0..n_jobs {
            d.submit(job(&format!("m{i}")), 0);
        }
        let mut to_host: VecDeque<(String, Vec<u8>)> = VecDeque::new();
        let mut finished: Vec<Finished> = vec![];
        let mut kills = 0;
        let mut now = 0u64;
        for _step in 0..20_000 {
            now += 1 + u64::try_from(rng.below(400)).unwrap();
            // The host publishes; the broker routes.
            while let Some((t, p)) = d.poll_transmit(now) {
                if t.starts_with(JOBS) {
                    let live: Vec<usize> = (0..ws.len()).filter(|&i| ws[i].alive).collect();
                    // One in five jobs is lost in flight; none reach a group with no member.
                    if !live.is_empty() && rng.below(5) != 0 {
                        ws[live[rng.below(live.len())]].inbox.push_back((t, p));
                    }
                } else {
                    let g: Grant = serde_json::from_slice(&p).unwrap();
                    let i: usize = g.worker[1..].parse().unwrap();
                    if ws[i].alive {
                        ws[i].inbox.push_back((t, p));
                    }
                }
            }
            match rng.below(10) {
                0..=5 => {
                    // A live worker takes its next message, or finishes its granted job.
                    let i = rng.below(ws.len());
                    let w = &mut ws[i];
                    let name = format!("w{i}");
                    if !w.alive {
                        continue;
                    }
                    if let Some(id) = w.granted.take() {
                        let r = JobResult {
                            job: id,
                            worker: name.clone(),
                            drift: drift(),
                        };
                        to_host.push_back((topic(RESULTS, &name), serde_json::to_vec(&r).unwrap()));
                    } else if let Some((t, p)) = w.inbox.pop_front() {
                        if t.starts_with(JOBS) && w.waiting.is_none() {
                            let j: Job = serde_json::from_slice(&p).unwrap();
                            w.waiting = Some(j.job);
                            let c = Claim {
                                job: j.job,
                                worker: name.clone(),
                            };
                            to_host
                                .push_back((topic(CLAIMS, &name), serde_json::to_vec(&c).unwrap()));
                        } else if t.starts_with(JOBS) {
                            // Busy: look at it later.
                            w.inbox.push_back((t, p));
                        } else {
                            let g: Grant = serde_json::from_slice(&p).unwrap();
                            if w.waiting == Some(g.job) {
                                w.waiting = None;
                                if g.granted {
                                    w.granted = Some(g.job);
                                }
                            }
                        }
                    }
                }
                6..=8 => {
                    if let Some((t, p)) = to_host.pop_front() {
                        d.handle_message(&t, &p, now);
                    }
                }
                _ => {
                    // Kill one (its will) or let it hang (no will: it keeps what it holds and
                    // does nothing more), at most two per run (the others finish the work).
                    let i = rng.below(ws.len());
                    if kills < 2 && ws[i].alive && rng.below(20) == 0 {
                        kills += 1;
                        ws[i].alive = false;
                        if rng.below(2) == 0 {
                            to_host.push_back((
                                topic(WORKERS, &format!("w{i}")),
                                br#"{"state":"offline"}"#.to_vec(),
                            ));
                        }
                    }
                }
            }
            finished.extend(std::iter::from_fn(|| d.poll_finished()));
            // No two live workers hold a grant for the same job.
            let mut held: Vec<u64> = ws
                .iter()
                .filter(|w| w.alive)
                .filter_map(|w| w.granted)
                .collect();
            let n = held.len();
            held.sort_unstable();
            held.dedup();
            assert_eq!(held.len(), n, "seed {seed}: a job granted twice");
            if d.unfinished() == 0 && to_host.is_empty() {
                break;
            }
        }
        assert_eq!(d.unfinished(), 0, "seed {seed}: work left");
        let mut ids: Vec<u64> = finished.iter().map(|f| f.job.job).collect();
        ids.sort_unstable();
        assert_eq!(ids, (1..=n_jobs).collect::<Vec<u64>>(), "seed {seed}");
        all_kills += kills;
        all_republished += d.republished;
        all_denied += d.denied;
        all_taken_back += d.taken_back;
    }
    assert!(
        all_kills > 50 && all_republished > 100 && all_denied > 100 && all_taken_back > 5,
        "the interleavings did not exercise the paths: {all_kills} kills, \
         {all_republished} republished, {all_denied} denied, {all_taken_back} taken back"
    );
}
