//! Latest-wins scheduling of queries.
//!
//! A SLAM system wants the answer about *now*. Each client slot (robot,
//! session, query kind) runs one query at a time and keeps at most
//! `capacity` queries waiting behind it; when a new query arrives at a full
//! slot, the oldest waiting one is answered at once as superseded and the
//! new one takes its place. A running query is never interrupted. Slots of
//! different robots, sessions or kinds never displace each other. A waiting
//! query whose caller goes away (cancellation, deadline) leaves its slot at
//! once, and if it had just been handed the turn, passes it on.

use super::request::QueryKind;
use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use tokio::sync::oneshot;

/// Whose queries compete with each other.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct SlotKey {
    /// The robot that asks.
    pub robot_id: String,
    /// Its SLAM session.
    pub session_id: String,
    /// The query kind (loop closure, relocalisation).
    pub kind: QueryKind,
}

/// The queries-waiting gauge.
fn waiting_gauge() -> prometheus::IntGauge {
    crate::metrics::QUEUE_DEPTH.with_label_values(&["queries"])
}

enum Turn {
    Run,
    Superseded,
}

struct Waiter {
    id: u64,
    wake: oneshot::Sender<Turn>,
}

#[derive(Default)]
struct Slot {
    running: bool,
    waiting: VecDeque<Waiter>,
}

/// The scheduler shared by all queries.
pub struct LatestWins {
    slots: Mutex<HashMap<SlotKey, Slot>>,
    capacity: usize,
    next_id: AtomicU64,
    superseded: AtomicU64,
}

/// The outcome of waiting for a turn.
pub enum Admission {
    /// Run now; the slot is held until the guard is dropped.
    Run(RunGuard),
    /// A newer query of the same client took this one's place.
    Superseded,
}

impl Admission {
    /// Whether the query got its turn (rather than being superseded).
    pub fn is_run(&self) -> bool {
        matches!(self, Admission::Run(_))
    }
}

/// Holds a slot's turn; dropping it hands the turn to the next waiter.
pub struct RunGuard {
    scheduler: Arc<LatestWins>,
    key: SlotKey,
}

impl Drop for RunGuard {
    fn drop(&mut self) {
        self.scheduler.release(&self.key);
    }
}

impl LatestWins {
    /// A scheduler keeping at most `capacity` (at least 1) queries waiting
    /// per slot.
    pub fn new(capacity: usize) -> Arc<LatestWins> {
        Arc::new(LatestWins {
            slots: Mutex::new(HashMap::new()),
            capacity: capacity.max(1),
            next_id: AtomicU64::new(0),
            superseded: AtomicU64::new(0),
        })
    }

    /// Queries answered as superseded so far.
    pub fn superseded(&self) -> u64 {
        self.superseded.load(Ordering::Relaxed)
    }

    /// Queries waiting in all slots.
    pub fn waiting(&self) -> usize {
        let slots = self.slots.lock().unwrap_or_else(|e| e.into_inner());
        slots.values().map(|s| s.waiting.len()).sum()
    }

    /// Waits for this query's turn in its slot.
    pub async fn admit(self: &Arc<Self>, key: SlotKey) -> Admission {
        let (id, receiver) = {
            let mut slots = self.slots.lock().unwrap_or_else(|e| e.into_inner());
            let slot = slots.entry(key.clone()).or_default();
            if !slot.running {
                slot.running = true;
                return Admission::Run(RunGuard {
                    scheduler: self.clone(),
                    key,
                });
            }
            if slot.waiting.len() >= self.capacity {
                if let Some(oldest) = slot.waiting.pop_front() {
                    self.superseded.fetch_add(1, Ordering::Relaxed);
                    waiting_gauge().dec();
                    let _ = oldest.wake.send(Turn::Superseded);
                }
            }
            let id = self.next_id.fetch_add(1, Ordering::Relaxed);
            let (wake, receiver) = oneshot::channel();
            slot.waiting.push_back(Waiter { id, wake });
            waiting_gauge().inc();
            (id, receiver)
        };
        let mut waiting = Waiting {
            scheduler: self.clone(),
            key: key.clone(),
            id,
            receiver,
            done: false,
        };
        let turn = (&mut waiting.receiver).await;
        waiting.done = true;
        match turn {
            Ok(Turn::Run) => Admission::Run(RunGuard {
                scheduler: self.clone(),
                key,
            }),
            Ok(Turn::Superseded) | Err(_) => Admission::Superseded,
        }
    }

    /// Hands the slot's turn to the oldest waiter still there, or frees it.
    fn release(&self, key: &SlotKey) {
        let mut slots = self.slots.lock().unwrap_or_else(|e| e.into_inner());
        let Some(slot) = slots.get_mut(key) else {
            return;
        };
        while let Some(next) = slot.waiting.pop_front() {
            waiting_gauge().dec();
            if next.wake.send(Turn::Run).is_ok() {
                return;
            }
        }
        slot.running = false;
        slots.remove(key);
    }
}

/// A query waiting for its turn; if dropped before it gets an answer (the
/// caller went away), it leaves the queue, passing on a turn it was given.
struct Waiting {
    scheduler: Arc<LatestWins>,
    key: SlotKey,
    id: u64,
    receiver: oneshot::Receiver<Turn>,
    done: bool,
}

impl Drop for Waiting {
    fn drop(&mut self) {
        if self.done {
            return;
        }
        self.receiver.close();
        if let Ok(Turn::Run) = self.receiver.try_recv() {
            self.scheduler.release(&self.key);
            return;
        }
        let mut slots = self
            .scheduler
            .slots
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(slot) = slots.get_mut(&self.key) {
            let before = slot.waiting.len();
            slot.waiting.retain(|w| w.id != self.id);
            waiting_gauge().sub((before - slot.waiting.len()) as i64);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn key(robot: &str, kind: u8) -> SlotKey {
        let kind = match kind {
            1 => QueryKind::LoopClosure,
            _ => QueryKind::Relocalisation,
        };
        SlotKey {
            robot_id: robot.into(),
            session_id: "s".into(),
            kind,
        }
    }

    /// Runs `n` queries of one client arriving while the first one runs;
    /// returns the indices answered.
    async fn burst(scheduler: &Arc<LatestWins>, n: usize) -> Vec<usize> {
        let first = match scheduler.admit(key("a", 1)).await {
            Admission::Run(guard) => guard,
            Admission::Superseded => panic!("an idle slot runs at once"),
        };
        let mut tasks = Vec::new();
        for i in 1..n {
            let s = scheduler.clone();
            tasks.push(tokio::spawn(async move {
                match s.admit(key("a", 1)).await {
                    Admission::Run(_guard) => Some(i),
                    Admission::Superseded => None,
                }
            }));
            // Let each arrive in order.
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        drop(first);
        let mut answered = vec![0];
        for t in tasks {
            answered.extend(t.await.unwrap());
        }
        answered
    }

    #[tokio::test]
    async fn a_burst_leaves_the_first_and_the_newest() {
        let scheduler = LatestWins::new(1);
        assert_eq!(burst(&scheduler, 10).await, vec![0, 9]);
        assert_eq!(scheduler.superseded(), 8);
        assert_eq!(scheduler.waiting(), 0);
    }

    #[tokio::test]
    async fn capacity_keeps_the_newest_few() {
        let scheduler = LatestWins::new(3);
        assert_eq!(burst(&scheduler, 10).await, vec![0, 7, 8, 9]);
        assert_eq!(scheduler.superseded(), 6);
    }

    #[tokio::test]
    async fn other_clients_and_kinds_do_not_compete() {
        let scheduler = LatestWins::new(1);
        let _a = scheduler.admit(key("a", 1)).await;
        assert!(matches!(
            scheduler.admit(key("b", 1)).await,
            Admission::Run(_)
        ));
        assert!(matches!(
            scheduler.admit(key("a", 2)).await,
            Admission::Run(_)
        ));
    }

    #[tokio::test]
    async fn a_cancelled_waiter_leaves_and_the_turn_moves_on() {
        let scheduler = LatestWins::new(2);
        let first = scheduler.admit(key("a", 1)).await;
        let s = scheduler.clone();
        let cancelled = tokio::spawn(async move { s.admit(key("a", 1)).await.is_run() });
        tokio::time::sleep(Duration::from_millis(10)).await;
        let s = scheduler.clone();
        let later = tokio::spawn(async move { s.admit(key("a", 1)).await.is_run() });
        tokio::time::sleep(Duration::from_millis(10)).await;
        assert_eq!(scheduler.waiting(), 2);
        cancelled.abort();
        tokio::time::sleep(Duration::from_millis(10)).await;
        assert_eq!(scheduler.waiting(), 1);
        drop(first);
        assert!(later.await.unwrap());
        assert_eq!(scheduler.superseded(), 0);
        // The slot is free again.
        assert!(scheduler.admit(key("a", 1)).await.is_run());
    }
}
