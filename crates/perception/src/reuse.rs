//! Objects carried over between the keyframes of one camera stream.
//!
//! A SLAM system makes a keyframe when the view has changed enough for its
//! tracking, which is far less than it takes to bring a new sign into view:
//! consecutive keyframes mostly show the same signs. Text detection and
//! recognition are most of what a keyframe costs a core
//! (docs/benchmarks.md, "Perception"), so where a keyframe's appearance
//! thumbnail (computed anyway, without a model) correlates with that of the
//! last keyframe of the same stream whose objects were detected and read
//! at or above [`ReuseConfig::min_similarity`], that keyframe's objects,
//! their text included, are carried over instead of running the detector
//! and OCR again. At most [`ReuseConfig::max_carried`] keyframes in a row
//! are served from one read, so a sign that enters the view at the edge is
//! read within that many keyframes. The comparison is always with the last
//! keyframe that was *read*, not the last one served, so a slow drift
//! cannot carry one read further and further from where it was made.
//!
//! Carried objects keep the positions they had in the image they were read
//! in; at the similarities allowed here, the view has moved by a few pixels.
//!
//! A stream is what the caller names one (the service: a robot's session);
//! the last read of at most [`ReuseConfig::max_sessions`] streams is kept,
//! the least recently used forgotten first. The service names a new stream
//! for a session once keyframes of it are erased (on any replica), and
//! forgets the old stream's read when the erasure came through it. Nothing
//! here is stored:
//! a restarted service reads the next keyframe of every stream afresh.

use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard};

use humem_core::keyframe::ObjectObservation;
use humem_core::vpr::appearance;

/// The `[perception.reuse]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReuseConfig {
    /// Most keyframes in a row whose objects are carried over from one
    /// read; 0 turns carrying off (every keyframe is detected and read).
    pub max_carried: u32,
    /// Correlation of the appearance thumbnails (−1..1) with the stream's
    /// last read keyframe at or above which its objects are carried over.
    pub min_similarity: f32,
    /// Streams whose last read is remembered at once.
    pub max_sessions: usize,
}

/// Default [`ReuseConfig::max_carried`].
pub const MAX_CARRIED: u32 = 0;
/// Default [`ReuseConfig::min_similarity`].
pub const MIN_SIMILARITY: f32 = 0.6;
/// Default [`ReuseConfig::max_sessions`]: a fleet server's sessions at
/// about 6 KiB each.
pub const MAX_SESSIONS: usize = 4096;

impl Default for ReuseConfig {
    fn default() -> Self {
        ReuseConfig {
            max_carried: MAX_CARRIED,
            min_similarity: MIN_SIMILARITY,
            max_sessions: MAX_SESSIONS,
        }
    }
}

impl ReuseConfig {
    /// Whether objects are ever carried over.
    pub fn enabled(&self) -> bool {
        self.max_carried > 0
    }

    /// Checks the settings (field names relative to the section).
    pub fn validate(&self) -> Result<(), String> {
        if !(self.min_similarity > 0.0 && self.min_similarity <= 1.0) {
            return Err(format!(
                "min_similarity must be in (0, 1], not {}",
                self.min_similarity
            ));
        }
        if self.max_sessions == 0 {
            return Err("max_sessions must be at least 1".into());
        }
        Ok(())
    }

    /// Whether a keyframe whose thumbnail correlates `similarity` with the
    /// stream's last read, after `carried` keyframes were already served
    /// from that read, is served from it too.
    pub fn carries(&self, similarity: f32, carried: u32) -> bool {
        carried < self.max_carried && similarity >= self.min_similarity
    }
}

/// The correlation of two patch-normalised thumbnails: their cosine, 0
/// where either is flat (all zeros) or they differ in length.
pub fn similarity(a: &[i8], b: &[i8]) -> f32 {
    if a.len() != b.len() {
        return 0.0;
    }
    let norms = appearance::norm(a) * appearance::norm(b);
    if norms <= 0.0 {
        return 0.0;
    }
    appearance::idot(a, b) as f32 / norms
}

/// The last read of one stream.
struct LastRead {
    thumbnail: Vec<i8>,
    objects: Vec<ObjectObservation>,
    /// Keyframes served from this read since it was made.
    carried: u32,
    /// When the stream was last seen, on [`Streams::clock`].
    seen: u64,
}

#[derive(Default)]
struct Streams {
    last: HashMap<String, LastRead>,
    clock: u64,
}

/// The last read of every stream, shared by concurrent requests.
pub struct ObjectReuse {
    config: ReuseConfig,
    streams: Mutex<Streams>,
}

impl ObjectReuse {
    /// Remembers reads as `config` says; `None` where carrying is off.
    pub fn new(config: &ReuseConfig) -> Option<ObjectReuse> {
        config.enabled().then(|| ObjectReuse {
            config: config.clone(),
            streams: Mutex::new(Streams::default()),
        })
    }

    /// The objects to carry over to a keyframe of `stream` with this
    /// thumbnail, if its last read may serve it (which then counts it).
    pub fn carry(&self, stream: &str, thumbnail: &[i8]) -> Option<Vec<ObjectObservation>> {
        let mut streams = self.lock();
        streams.clock += 1;
        let now = streams.clock;
        let last = streams.last.get_mut(stream)?;
        last.seen = now;
        if !self
            .config
            .carries(similarity(thumbnail, &last.thumbnail), last.carried)
        {
            return None;
        }
        last.carried += 1;
        Some(last.objects.clone())
    }

    /// Makes `objects`, just detected and read in the image of `thumbnail`,
    /// the last read of `stream`.
    pub fn remember(&self, stream: &str, thumbnail: Vec<i8>, objects: Vec<ObjectObservation>) {
        let mut streams = self.lock();
        streams.clock += 1;
        let seen = streams.clock;
        let read = LastRead {
            thumbnail,
            objects,
            carried: 0,
            seen,
        };
        if let Some(last) = streams.last.get_mut(stream) {
            *last = read;
            return;
        }
        if streams.last.len() >= self.config.max_sessions {
            let oldest = streams
                .last
                .iter()
                .min_by_key(|(_, r)| r.seen)
                .map(|(k, _)| k.clone());
            if let Some(oldest) = oldest {
                streams.last.remove(&oldest);
            }
        }
        streams.last.insert(stream.to_string(), read);
    }

    /// The streams; a panic while they were held left nothing half-done
    /// that matters (a read is replaced whole).
    fn lock(&self) -> MutexGuard<'_, Streams> {
        self.streams.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Forgets the last read of `stream`.
    pub fn forget(&self, stream: &str) {
        self.lock().last.remove(stream);
    }

    /// Streams remembered now.
    pub fn streams(&self) -> usize {
        self.lock().last.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use humem_core::keyframe::TextObservation;

    fn config(max_carried: u32, min_similarity: f32, max_sessions: usize) -> ReuseConfig {
        ReuseConfig {
            max_carried,
            min_similarity,
            max_sessions,
        }
    }

    fn sign(text: &str) -> Vec<ObjectObservation> {
        vec![ObjectObservation {
            class_name: "sign".into(),
            confidence: 0.9,
            centroid: [0.5, 0.5],
            area: 0.01,
            texts: vec![TextObservation {
                text: text.into(),
                confidence: 0.9,
            }],
        }]
    }

    #[test]
    fn similarity_by_hand() {
        // a·b = 3·1 + 4·2 = 11, |a| = 5, |b| = √5: 11 / (5 √5) = 0.98387.
        let s = similarity(&[3, 4], &[1, 2]);
        assert!((s - 11.0 / (5.0 * 5f32.sqrt())).abs() < 1e-6, "{s}");
        assert!((similarity(&[1, -1], &[-1, 1]) + 1.0).abs() < 1e-6);
        assert_eq!(similarity(&[0, 0], &[1, 2]), 0.0, "a flat thumbnail");
        assert_eq!(similarity(&[1, 2], &[1, 2, 3]), 0.0, "lengths differ");
    }

    #[test]
    fn carries_up_to_max_carried_above_min_similarity() {
        let c = config(2, 0.8, 8);
        assert!(c.carries(0.8, 0));
        assert!(c.carries(0.95, 1));
        assert!(!c.carries(0.95, 2), "two served already");
        assert!(!c.carries(0.79, 0), "too different");
        assert!(!config(0, 0.8, 8).enabled());
    }

    #[test]
    fn validation_names_the_field() {
        assert!(ReuseConfig::default().validate().is_ok());
        let e = config(2, 0.0, 8).validate().unwrap_err();
        assert!(e.starts_with("min_similarity"), "{e}");
        let e = config(2, 1.5, 8).validate().unwrap_err();
        assert!(e.starts_with("min_similarity"), "{e}");
        let e = config(2, 0.8, 0).validate().unwrap_err();
        assert!(e.starts_with("max_sessions"), "{e}");
        assert!(ObjectReuse::new(&config(0, 0.8, 8)).is_none(), "off");
    }

    #[test]
    fn a_read_serves_similar_keyframes_of_its_stream_a_bounded_number_of_times() {
        let reuse = ObjectReuse::new(&config(2, 0.9, 8)).unwrap();
        let view = [10i8, 20, 30, 40];
        let nudged = [11i8, 20, 29, 40]; // similarity 0.9993
        let elsewhere = [40i8, -30, 20, -10]; // similarity 0.0
        assert_eq!(reuse.carry("robot/a", &view), None, "nothing read yet");
        reuse.remember("robot/a", view.to_vec(), sign("CEDAR AVE"));
        assert_eq!(reuse.carry("robot/b", &view), None, "another stream");
        assert_eq!(reuse.carry("robot/a", &elsewhere), None);
        assert_eq!(reuse.carry("robot/a", &nudged), Some(sign("CEDAR AVE")));
        assert_eq!(reuse.carry("robot/a", &view), Some(sign("CEDAR AVE")));
        assert_eq!(reuse.carry("robot/a", &view), None, "max_carried reached");
        // The next read starts the count again.
        reuse.remember("robot/a", nudged.to_vec(), sign("ACME BAKERY"));
        assert_eq!(reuse.carry("robot/a", &view), Some(sign("ACME BAKERY")));
    }

    #[test]
    fn the_least_recently_seen_stream_is_forgotten_first() {
        let reuse = ObjectReuse::new(&config(5, 0.9, 2)).unwrap();
        let view = [1i8, 2, 3];
        reuse.remember("a", view.to_vec(), sign("A"));
        reuse.remember("b", view.to_vec(), sign("B"));
        // "a" is seen again, so "b" is now the oldest.
        assert!(reuse.carry("a", &view).is_some());
        reuse.remember("c", view.to_vec(), sign("C"));
        assert_eq!(reuse.streams(), 2);
        assert_eq!(reuse.carry("b", &view), None, "forgotten");
        assert_eq!(reuse.carry("a", &view), Some(sign("A")));
        assert_eq!(reuse.carry("c", &view), Some(sign("C")));
        reuse.forget("c");
        assert_eq!(reuse.carry("c", &view), None, "forgotten on request");
        assert_eq!(reuse.streams(), 1);
    }
}
