//! Admission of queries across all robots.
//!
//! Latest-wins ([`super::latest_wins`]) keeps one robot from queueing
//! behind itself, but a fleet of robots can still ask for more scans than
//! the cores can run. Every scan already uses every scan thread, so running
//! more of them at once only makes each slower, and it holds the index's
//! read lock longer, which the store writer must wait out before it can
//! publish an insert. So at most `concurrent` scans run; the rest wait in
//! arrival order. A query that must wait and whose expected answer time
//! (the scans ahead of it, each at the recent scan time of its kind, plus
//! its own scan), counted from its arrival, is longer than its budget (the
//! configured one, or the caller's deadline if shorter) is refused at once
//! with RESOURCE_EXHAUSTED and a retry hint, rather than answered after
//! its caller has given up; so the queries that are admitted are answered
//! within the budget.
//!
//! The recent scan time is kept per [`ScanKind`]: on a fleet's store a
//! query that asks for the exact pass costs a hundred times one answered
//! through the neighbour graph, and one mean over both made every query
//! look as slow as the last exact one, so that a server answering in
//! milliseconds refused most of what it was asked.
//!
//! An exact pass over a large store reads it in pieces and, between two
//! pieces, gives its slot to the planned queries waiting
//! ([`ScanSlot::give_way`]) before it goes on: a few exact queries an hour
//! (or a sample that checks the planner) then delay the fleet's queries by
//! a piece each, not by a pass, and a planned query counts each exact one
//! ahead of it at the recent time of such a stretch.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// What a query's scan is expected to cost, by how it asked to be
/// answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScanKind {
    /// As the planner chooses: the neighbour graph's candidates over a
    /// large eligible set, an exact pass over a small one.
    Planned = 0,
    /// The exact pass over every eligible keyframe, whatever their number
    /// (`exact` on the query, or `vpr.exact`).
    Exact = 1,
}

/// The shared admission state.
#[derive(Debug)]
pub struct QueryAdmission {
    slots: Arc<Semaphore>,
    concurrent: usize,
    /// Queries running or waiting, per [`ScanKind`].
    queued: [AtomicUsize; 2],
    /// Queries holding a slot, per [`ScanKind`].
    running: [AtomicUsize; 2],
    /// Recent scan time per [`ScanKind`], an exponentially weighted mean,
    /// in microseconds (0: none yet).
    scan_micros: [AtomicU64; 2],
    /// Recent time an exact pass held its slot before it gave way, the
    /// same kind of mean (0: none gave way yet).
    stretch_micros: AtomicU64,
    budget: Duration,
}

/// A query that may not wait for its scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "server busy: {ahead} queries ahead, expected answer in {} ms, more than this query has left ({} ms); retry after {} ms",
    expected.as_millis(), budget.as_millis(), expected.as_millis()
)]
pub struct Busy {
    /// Scans running or waiting when the query arrived.
    pub ahead: usize,
    /// How long it would have taken to answer: the wait for a slot and
    /// the scan.
    pub expected: Duration,
    /// What was left of its budget or deadline when it arrived here.
    pub budget: Duration,
}

/// The right to run one scan; dropping it records the scan's time and lets
/// the next query in.
#[derive(Debug)]
pub struct ScanSlot {
    started: Instant,
    // Uncounted before the slot is let go (fields drop in this order).
    queued: Queued,
    /// The slot, and since when this scan holds it; None only while an
    /// exact pass waits to get it back ([`ScanSlot::give_way`]).
    permit: Mutex<Option<(OwnedSemaphorePermit, Instant)>>,
}

impl Drop for ScanSlot {
    fn drop(&mut self) {
        let queued = &self.queued;
        queued.admission.record(queued.kind, self.started.elapsed());
        queued.admission.running[queued.kind as usize].fetch_sub(1, Ordering::Relaxed);
    }
}

impl ScanSlot {
    /// For an exact pass, between two of its pieces: when planned queries
    /// wait for a slot, lets this one go, then waits for it again behind
    /// every query that was waiting. Blocks the calling thread, so it is
    /// for a scan's blocking thread (inside the runtime that admitted the
    /// query), never for async code. Planned scans never give way.
    pub fn give_way(&self) {
        let admission = &self.queued.admission;
        if self.queued.kind != ScanKind::Exact || admission.waiting_of(ScanKind::Planned) == 0 {
            return;
        }
        let mut permit = self.permit.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((held, since)) = permit.take() {
            drop(held);
            admission.record_stretch(since.elapsed());
        }
        admission.running[ScanKind::Exact as usize].fetch_sub(1, Ordering::Relaxed);
        let again = tokio::runtime::Handle::current()
            .block_on(admission.slots.clone().acquire_owned())
            .expect("the admission semaphore is never closed");
        admission.running[ScanKind::Exact as usize].fetch_add(1, Ordering::Relaxed);
        *permit = Some((again, Instant::now()));
    }
}

/// A query counted among those running or waiting, until dropped.
#[derive(Debug)]
struct Queued {
    admission: Arc<QueryAdmission>,
    kind: ScanKind,
}

impl Drop for Queued {
    fn drop(&mut self) {
        self.admission.queued[self.kind as usize].fetch_sub(1, Ordering::Relaxed);
    }
}

impl QueryAdmission {
    /// At most `concurrent` (≥ 1) scans at once; queries wait at most
    /// `budget` for theirs.
    pub fn new(concurrent: usize, budget: Duration) -> Arc<QueryAdmission> {
        let concurrent = concurrent.max(1);
        Arc::new(QueryAdmission {
            slots: Arc::new(Semaphore::new(concurrent)),
            concurrent,
            queued: [AtomicUsize::new(0), AtomicUsize::new(0)],
            running: [AtomicUsize::new(0), AtomicUsize::new(0)],
            scan_micros: [AtomicU64::new(0), AtomicU64::new(0)],
            stretch_micros: AtomicU64::new(0),
            budget,
        })
    }

    /// The recent scan time of `kind`; that of the other kind until one
    /// of `kind` has run.
    fn scan_time(&self, kind: ScanKind) -> u64 {
        let mean = |k: usize| self.scan_micros[k].load(Ordering::Relaxed);
        match mean(kind as usize) {
            0 => mean(1 - kind as usize),
            known => known,
        }
    }

    /// How long an exact scan ahead holds up a query of `kind`: its whole
    /// pass for another exact one; for a planned one, the recent stretch
    /// an exact pass held its slot before it gave way (its whole pass
    /// until one has given way: passes over small stores never do).
    fn exact_time_for(&self, kind: ScanKind) -> u64 {
        match (kind, self.stretch_micros.load(Ordering::Relaxed)) {
            (ScanKind::Planned, stretch) if stretch > 0 => stretch,
            _ => self.scan_time(ScanKind::Exact),
        }
    }

    /// The queries running or waiting now, and how long a query of `kind`
    /// arriving now would wait for a slot: the rounds of `concurrent`
    /// scans ahead of it, each round as long as the mean scan ahead.
    fn ahead(&self, kind: ScanKind) -> (usize, Duration) {
        let counts = self.queued.each_ref().map(|q| q.load(Ordering::Relaxed));
        let ahead: usize = counts.iter().sum();
        let rounds = (ahead + 1)
            .saturating_sub(self.concurrent)
            .div_ceil(self.concurrent);
        if rounds == 0 {
            return (ahead, Duration::ZERO);
        }
        let work = counts[ScanKind::Planned as usize] as u64 * self.scan_time(ScanKind::Planned)
            + counts[ScanKind::Exact as usize] as u64 * self.exact_time_for(kind);
        (
            ahead,
            Duration::from_micros(work / ahead as u64 * rounds as u64),
        )
    }

    /// Waits for a scan slot for a scan of `kind`, or refuses at once when
    /// the query would have to wait for one and could not be answered in
    /// time: when the expected wait plus its kind's recent scan time is longer than what is left
    /// of the budget or of `deadline` (what the caller will wait), both
    /// counted from the query's arrival, `waited` ago (its turn behind its
    /// own robot's previous query and its perception count too). So an
    /// admitted query is expected to be answered within the budget, not to
    /// start by then. A query that finds a slot free always runs.
    pub async fn admit(
        self: &Arc<Self>,
        kind: ScanKind,
        waited: Duration,
        deadline: Option<Duration>,
    ) -> Result<ScanSlot, Busy> {
        let (ahead, wait) = self.ahead(kind);
        let scan = Duration::from_micros(self.scan_time(kind));
        let expected = wait + scan;
        let budget = deadline
            .map_or(self.budget, |d| d.min(self.budget))
            .saturating_sub(waited);
        // A free slot is always taken: refusing there would refuse every
        // query of a store whose scan alone outlasts the budget.
        if !wait.is_zero() && expected > budget {
            return Err(Busy {
                ahead,
                expected,
                budget,
            });
        }
        self.queued[kind as usize].fetch_add(1, Ordering::Relaxed);
        // Uncounted however the wait ends (a caller that goes away drops
        // the future).
        let queued = Queued {
            admission: self.clone(),
            kind,
        };
        let permit = self
            .slots
            .clone()
            .acquire_owned()
            .await
            .expect("the admission semaphore is never closed");
        self.running[kind as usize].fetch_add(1, Ordering::Relaxed);
        let started = Instant::now();
        Ok(ScanSlot {
            started,
            queued,
            permit: Mutex::new(Some((permit, started))),
        })
    }

    /// Queries waiting for a slot: those counted, less those running.
    #[cfg(test)]
    fn waiting(&self) -> usize {
        self.waiting_of(ScanKind::Planned) + self.waiting_of(ScanKind::Exact)
    }

    /// Queries of `kind` waiting for a slot (an exact pass that gave way
    /// counts among them until it has its slot back).
    fn waiting_of(&self, kind: ScanKind) -> usize {
        let k = kind as usize;
        self.queued[k]
            .load(Ordering::Relaxed)
            .saturating_sub(self.running[k].load(Ordering::Relaxed))
    }

    /// Folds one scan's time into its kind's recent mean.
    fn record(&self, kind: ScanKind, took: Duration) {
        fold(&self.scan_micros[kind as usize], took);
    }

    /// Folds how long an exact pass held its slot before it gave way into
    /// the recent mean of such stretches.
    fn record_stretch(&self, held: Duration) {
        fold(&self.stretch_micros, held);
    }
}

/// Folds `took` into the exponentially weighted mean in `mean` (weight
/// 1/4; the first time recorded is the mean).
fn fold(mean: &AtomicU64, took: Duration) {
    let took = took.as_micros().min(u128::from(u64::MAX)) as u64;
    let _ = mean.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |mean| {
        Some(if mean == 0 {
            took
        } else {
            (3 * mean + took) / 4
        })
    });
}

/// The caller's deadline from a `grpc-timeout` header value (`"250m"`:
/// an integer and a unit, H M S m u n), or `None` when absent or malformed.
pub fn grpc_timeout(value: &str) -> Option<Duration> {
    let (digits, unit) = value.split_at(value.len().checked_sub(1)?);
    let n: u64 = digits.parse().ok()?;
    Some(match unit {
        "H" => Duration::from_secs(n.checked_mul(3600)?),
        "M" => Duration::from_secs(n.checked_mul(60)?),
        "S" => Duration::from_secs(n),
        "m" => Duration::from_millis(n),
        "u" => Duration::from_micros(n),
        "n" => Duration::from_nanos(n),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timeouts_parse_as_grpc_writes_them() {
        assert_eq!(grpc_timeout("250m"), Some(Duration::from_millis(250)));
        assert_eq!(grpc_timeout("3S"), Some(Duration::from_secs(3)));
        assert_eq!(grpc_timeout("2M"), Some(Duration::from_secs(120)));
        assert_eq!(grpc_timeout("1H"), Some(Duration::from_secs(3600)));
        assert_eq!(grpc_timeout("5u"), Some(Duration::from_micros(5)));
        assert_eq!(grpc_timeout("7n"), Some(Duration::from_nanos(7)));
        for bad in ["", "m", "12", "12x", "-1m", "1.5S"] {
            assert_eq!(grpc_timeout(bad), None, "{bad:?}");
        }
    }

    #[tokio::test]
    async fn queries_that_could_not_be_answered_within_the_budget_are_refused_at_once() {
        let admission = QueryAdmission::new(1, Duration::from_millis(200));
        // Recent scans take 80 ms (the first time recorded is the mean).
        admission.record(ScanKind::Planned, Duration::from_millis(80));
        let running = admit_now(&admission, ScanKind::Planned).await.unwrap();
        // One ahead: 80 ms to wait and 80 to scan, within 200 ms.
        let second = {
            let a = admission.clone();
            tokio::spawn(async move { admit_now(&a, ScanKind::Planned).await.map(|_| ()) })
        };
        tokio::task::yield_now().await;
        while admission.waiting() == 0 {
            tokio::task::yield_now().await;
        }
        // Two ahead: 160 + 80 ms > 200 ms: refused, saying why.
        let busy = admit_now(&admission, ScanKind::Planned).await.unwrap_err();
        assert_eq!(busy.ahead, 2);
        assert!(busy.expected >= Duration::from_millis(230), "{busy:?}");
        assert!(busy.to_string().contains("retry after"));
        // Two near-instant scans bring the mean to 45 ms. With one scan
        // running, a caller with a 20 ms deadline is refused, and so is
        // one that already spent 190 ms of the budget waiting for its
        // turn; with the slot free, both run.
        drop(running);
        second.await.unwrap().unwrap();
        let running = admit_now(&admission, ScanKind::Planned).await.unwrap();
        let short = admission
            .admit(
                ScanKind::Planned,
                Duration::ZERO,
                Some(Duration::from_millis(20)),
            )
            .await
            .unwrap_err();
        assert_eq!(short.budget, Duration::from_millis(20));
        let late = admission
            .admit(ScanKind::Planned, Duration::from_millis(190), None)
            .await
            .unwrap_err();
        assert_eq!(late.budget, Duration::from_millis(10));
        drop(running);
        drop(
            admission
                .admit(
                    ScanKind::Planned,
                    Duration::ZERO,
                    Some(Duration::from_millis(20)),
                )
                .await
                .unwrap(),
        );
        drop(
            admission
                .admit(ScanKind::Planned, Duration::from_millis(190), None)
                .await
                .unwrap(),
        );
        // The waiting count returns to zero when a waiter gives up.
        let hold = admit_now(&admission, ScanKind::Planned).await.unwrap();
        let gave_up = tokio::time::timeout(
            Duration::from_millis(10),
            admission.admit(ScanKind::Planned, Duration::ZERO, None),
        )
        .await;
        assert!(gave_up.is_err());
        assert_eq!(admission.waiting(), 0);
        drop(hold);
    }

    /// Asks `admission` for a slot for a query of `kind` that has not
    /// waited and has no deadline of its own.
    async fn admit_now(admission: &Arc<QueryAdmission>, kind: ScanKind) -> Result<ScanSlot, Busy> {
        admission.admit(kind, Duration::ZERO, None).await
    }

    /// A planned query admitted in a task of its own, once it waits for
    /// its slot (or was refused: the task then holds the refusal).
    async fn quick_query_waiting(
        admission: &Arc<QueryAdmission>,
    ) -> tokio::task::JoinHandle<Result<(), Busy>> {
        let a = admission.clone();
        let task = tokio::spawn(async move { admit_now(&a, ScanKind::Planned).await.map(|_| ()) });
        while admission.waiting() == 0 && !task.is_finished() {
            tokio::task::yield_now().await;
        }
        task
    }

    #[tokio::test]
    async fn a_slow_exact_scan_does_not_make_quick_queries_look_slow() {
        let admission = QueryAdmission::new(1, Duration::from_millis(250));
        admission.record(ScanKind::Planned, Duration::from_millis(5));
        // An exact pass over a large store: 600 ms.
        admission.record(ScanKind::Exact, Duration::from_millis(600));
        let running = admit_now(&admission, ScanKind::Planned).await.unwrap();
        // One quick scan ahead: 5 + 5 ms, admitted.
        let quick = quick_query_waiting(&admission).await;
        // An exact query behind two quick ones would take 610 ms: refused,
        // its own kind's time counted.
        let busy = admit_now(&admission, ScanKind::Exact).await.unwrap_err();
        assert_eq!(busy.ahead, 2);
        assert!(busy.expected >= Duration::from_millis(600), "{busy:?}");
        drop(running);
        quick.await.unwrap().unwrap();
        // With an exact scan running, a quick query expects its 600 ms.
        let exact = admit_now(&admission, ScanKind::Exact).await.unwrap();
        let behind = admit_now(&admission, ScanKind::Planned).await.unwrap_err();
        assert!(behind.expected >= Duration::from_millis(600), "{behind:?}");
        drop(exact);
        assert_eq!(
            admission.queued[ScanKind::Exact as usize].load(Ordering::Relaxed),
            0
        );
        // Once it is done, quick queries behind quick ones are admitted
        // again: the exact scan's time is not in their mean.
        let running = admit_now(&admission, ScanKind::Planned).await.unwrap();
        let next = quick_query_waiting(&admission).await;
        drop(running);
        next.await.unwrap().unwrap();
        assert_eq!(
            admission.queued[ScanKind::Planned as usize].load(Ordering::Relaxed),
            0
        );
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn an_exact_pass_gives_its_slot_to_the_planned_queries_waiting() {
        let admission = QueryAdmission::new(1, Duration::from_secs(10));
        let exact = admit_now(&admission, ScanKind::Exact).await.unwrap();
        // Nobody waits: the pass keeps its slot.
        let exact = tokio::task::spawn_blocking(move || {
            exact.give_way();
            exact
        })
        .await
        .unwrap();
        assert_eq!(admission.slots.available_permits(), 0);
        assert_eq!(admission.stretch_micros.load(Ordering::Relaxed), 0);
        // A planned query waits: the pass lets it run first and goes on
        // once it is done.
        let (ran, mut ran_seen) = tokio::sync::oneshot::channel();
        let planned = {
            let a = admission.clone();
            tokio::spawn(async move {
                let slot = admit_now(&a, ScanKind::Planned).await.unwrap();
                tokio::time::sleep(Duration::from_millis(30)).await;
                ran.send(()).unwrap();
                drop(slot);
            })
        };
        while admission.waiting_of(ScanKind::Planned) == 0 {
            tokio::task::yield_now().await;
        }
        let exact = tokio::task::spawn_blocking(move || {
            exact.give_way();
            exact
        })
        .await
        .unwrap();
        ran_seen
            .try_recv()
            .expect("the planned query ran while the pass waited");
        planned.await.unwrap();
        assert_eq!(
            admission.slots.available_permits(),
            0,
            "the pass has its slot back"
        );
        assert!(admission.stretch_micros.load(Ordering::Relaxed) > 0);
        assert_eq!(
            admission.running[ScanKind::Exact as usize].load(Ordering::Relaxed),
            1
        );
        drop(exact);
        assert_eq!(admission.slots.available_permits(), 1);
        assert_eq!(
            admission
                .running
                .each_ref()
                .map(|r| r.load(Ordering::Relaxed)),
            [0, 0]
        );
        // A planned scan never gives way.
        let planned = admit_now(&admission, ScanKind::Planned).await.unwrap();
        let waiting = quick_query_waiting(&admission).await;
        let planned = tokio::task::spawn_blocking(move || {
            planned.give_way();
            planned
        })
        .await
        .unwrap();
        assert_eq!(admission.waiting_of(ScanKind::Planned), 1);
        drop(planned);
        waiting.await.unwrap().unwrap();
    }

    #[tokio::test]
    async fn a_quick_query_behind_an_exact_pass_that_gives_way_expects_a_stretch() {
        let admission = QueryAdmission::new(1, Duration::from_millis(250));
        admission.record(ScanKind::Planned, Duration::from_millis(5));
        admission.record(ScanKind::Exact, Duration::from_millis(600));
        // Passes held their slot 20 ms at a time before giving way.
        admission.record_stretch(Duration::from_millis(20));
        let exact = admit_now(&admission, ScanKind::Exact).await.unwrap();
        // A quick query behind it expects 20 + 5 ms: admitted.
        let quick = quick_query_waiting(&admission).await;
        // Another exact query still counts the whole pass ahead of it.
        let busy = admit_now(&admission, ScanKind::Exact).await.unwrap_err();
        assert!(busy.expected >= Duration::from_millis(600), "{busy:?}");
        drop(exact);
        quick.await.unwrap().unwrap();
    }
}
