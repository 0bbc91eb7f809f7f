//! Per-robot quotas: keyframes inserted per second, queries per second, and
//! keyframes held in the store. A robot over one is answered
//! RESOURCE_EXHAUSTED with a `retry-after-ms` hint (for the rates: when the
//! next call would pass) and counted by kind, never by robot, so the
//! metric's cardinality stays bounded however many robots there are.
//!
//! The rates are GCRA token buckets (`governor`, keyed by robot id), with a
//! burst of one second's worth: a robot may catch up after a short link
//! outage, but not exceed its rate for longer. Idle robots' buckets are
//! dropped now and then, so their memory is bounded too.

use std::num::NonZeroU32;
use std::time::Duration;

use governor::clock::{Clock, DefaultClock};
use governor::{DefaultKeyedRateLimiter, Quota};
use tonic::Status;

use crate::config::QuotaConfig;
use crate::metrics;
use humem_core::keyframe::KeyframeKey;
use humem_store::Store;

/// The limiters.
pub struct Quotas {
    inserts: Option<DefaultKeyedRateLimiter<String>>,
    queries: Option<DefaultKeyedRateLimiter<String>>,
    max_keyframes: u64,
    clock: DefaultClock,
}

/// Calls between sweeps of idle robots' buckets.
const SWEEP_EVERY: u64 = 4096;

fn limiter(per_second: u32) -> Option<DefaultKeyedRateLimiter<String>> {
    NonZeroU32::new(per_second).map(|rate| DefaultKeyedRateLimiter::keyed(Quota::per_second(rate)))
}

/// RESOURCE_EXHAUSTED with a `retry-after-ms` hint, counted by `kind`.
pub fn exhausted(kind: &'static str, message: String, retry: Duration) -> Status {
    metrics::QUOTA_REFUSED.with_label_values(&[kind]).inc();
    let mut status = Status::resource_exhausted(message);
    let ms = u32::try_from(retry.as_millis()).unwrap_or(u32::MAX).max(1);
    status
        .metadata_mut()
        .insert("retry-after-ms", tonic::metadata::MetadataValue::from(ms));
    status
}

impl Quotas {
    /// The limiters of `config`.
    pub fn new(config: &QuotaConfig) -> Quotas {
        Quotas {
            inserts: limiter(config.inserts_per_second),
            queries: limiter(config.queries_per_second),
            max_keyframes: config.max_keyframes_per_robot,
            clock: DefaultClock::default(),
        }
    }

    fn take(
        &self,
        limiter: &Option<DefaultKeyedRateLimiter<String>>,
        kind: &'static str,
        what: &str,
        robot: &str,
        n: usize,
    ) -> Result<(), Status> {
        let Some(limiter) = limiter else {
            return Ok(());
        };
        if sweep_due() {
            limiter.retain_recent();
        }
        let cells = NonZeroU32::new(u32::try_from(n.max(1)).unwrap_or(u32::MAX)).expect("n >= 1");
        let key = robot.to_string();
        match limiter.check_key_n(&key, cells) {
            Ok(Ok(())) => Ok(()),
            Ok(Err(not_until)) => Err(exhausted(
                kind,
                format!("robot {robot:?} is over its quota of {what} per second; retry later"),
                not_until.wait_time_from(self.clock.now()),
            )),
            Err(capacity) => Err(exhausted(
                kind,
                format!(
                    "{n} {what} in one call exceed robot {robot:?}'s quota of {} per second: send fewer at once",
                    capacity.0
                ),
                Duration::from_secs(1),
            )),
        }
    }

    /// Takes `n` keyframes from `robot`'s insert rate.
    pub fn inserts(&self, robot: &str, n: usize) -> Result<(), Status> {
        self.take(&self.inserts, "insert_rate", "keyframes", robot, n)
    }

    /// Takes one query from `robot`'s query rate.
    pub fn query(&self, robot: &str) -> Result<(), Status> {
        self.take(&self.queries, "query_rate", "queries", robot, 1)
    }

    /// Whether storing `keys` keeps each robot within its keyframe quota
    /// (keys already stored replace themselves and add nothing), as far as
    /// this replica's index knows: a cheap first look, so that a robot at
    /// its quota is refused before its image is perceived. The exact check
    /// is the store writer's, as the insert is applied
    /// ([`humem_store::Mutation::InsertWithin`]).
    pub async fn store_size(&self, store: &Store, keys: &[&KeyframeKey]) -> Result<(), Status> {
        if self.max_keyframes == 0 {
            return Ok(());
        }
        let index = store.index_async().await;
        let mut added: std::collections::BTreeMap<&str, u64> = Default::default();
        for key in keys {
            if index.row_of(key).is_none() {
                *added.entry(key.robot_id.as_str()).or_default() += 1;
            }
        }
        if added.is_empty() {
            return Ok(());
        }
        for (robot, new) in added {
            let held = index.robot_keyframes(robot) as u64;
            if held + new > self.max_keyframes {
                return Err(exhausted(
                    "store_size",
                    format!(
                        "robot {robot:?} holds {held} keyframes and its quota is {}: erase or reset some first",
                        self.max_keyframes
                    ),
                    Duration::from_secs(60),
                ));
            }
        }
        Ok(())
    }
}

/// True about once every [`SWEEP_EVERY`] calls.
fn sweep_due() -> bool {
    use std::sync::atomic::{AtomicU64, Ordering};
    static CALLS: AtomicU64 = AtomicU64::new(0);
    CALLS.fetch_add(1, Ordering::Relaxed) % SWEEP_EVERY == SWEEP_EVERY - 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_refuse_beyond_a_second_of_burst_with_a_hint() {
        let quotas = Quotas::new(&QuotaConfig {
            inserts_per_second: 10,
            queries_per_second: 2,
            max_keyframes_per_robot: 0,
        });
        quotas.inserts("a", 6).unwrap();
        quotas.inserts("a", 4).unwrap();
        let status = quotas.inserts("a", 1).unwrap_err();
        assert_eq!(status.code(), tonic::Code::ResourceExhausted);
        let retry: u32 = status
            .metadata()
            .get("retry-after-ms")
            .unwrap()
            .to_str()
            .unwrap()
            .parse()
            .unwrap();
        assert!((1..=100).contains(&retry), "{retry}");
        // Another robot has its own bucket.
        quotas.inserts("b", 10).unwrap();
        // More than a burst in one call can never pass.
        let status = quotas.inserts("c", 11).unwrap_err();
        assert!(
            status.message().contains("send fewer at once"),
            "{status:?}"
        );
        quotas.query("a").unwrap();
        quotas.query("a").unwrap();
        assert!(quotas.query("a").is_err());
        // No limit configured: everything passes.
        let open = Quotas::new(&QuotaConfig::default());
        open.inserts("a", 1_000_000).unwrap();
        open.query("a").unwrap();
    }
}
