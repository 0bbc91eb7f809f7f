//! How close the HuMem-VPR query is to the memory-bandwidth bound.
//!
//! SCAL scans every stored descriptor, so a query can be no faster than one
//! pass of dot products over the descriptor matrix. Each group measures
//! that pass (`baseline_dot_scan`) next to SCAL (eligibility, scene
//! modulation, temporal context, top-K) and the full ranking (SCAL plus OSRL
//! and OGTL on the top K), over the real in-memory index, so the ratio
//! between them is the cost of everything that is not reading descriptors.
//!
//! Keyframes carry 16 scene classes (the default `store.scene_top_k`),
//! four objects, two with text, and an appearance thumbnail, which SCAL
//! scans beside the descriptor (`vpr.appearance_weight`). Run with `cargo bench -p humem --bench rank`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use humem_core::index::Index;
use humem_core::keyframe::{
    Features, KeyframeKey, ObjectObservation, Pose, SceneClass, SemanticKeyframe, TextObservation,
};
use humem_core::vpr;
use humem_core::vpr::memory::KeyframeMemory;
use humem_core::vpr::params::{Layers, VprParams};
use humem_core::vpr::rank::QueryObservation;
use humem_core::vpr::scal::ScalQuery;

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn features(rng: &mut Rng, dim: usize, place: usize) -> Features {
    let mut descriptor: Vec<f32> = (0..dim).map(|_| rng.next() - 0.5).collect();
    let norm = descriptor.iter().map(|v| v * v).sum::<f32>().sqrt();
    descriptor.iter_mut().for_each(|v| *v /= norm);
    let object = |class: &str, x: f32, text: Option<String>| ObjectObservation {
        class_name: class.into(),
        confidence: 0.8,
        centroid: [x, 0.4],
        area: 0.05,
        texts: text
            .into_iter()
            .map(|text| TextObservation {
                text,
                confidence: 0.9,
            })
            .collect(),
    };
    Features {
        descriptor,
        scene: (0..16)
            .map(|k| SceneClass {
                class_id: ((place + k) % 365) as u32,
                probability: 0.05,
            })
            .collect(),
        objects: vec![
            object("sign", rng.next(), Some(format!("ROOM {}", place % 500))),
            object("sign", rng.next(), Some("EXIT".into())),
            object("building", rng.next(), None),
            object("street_light", rng.next(), None),
        ],
        appearance: (0..vpr::appearance::LEN)
            .map(|_| ((rng.next() - 0.5) * 120.0) as i8)
            .collect(),
    }
}

fn index(n: usize, dim: usize) -> Index {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut index = Index::new(dim);
    for i in 0..n {
        index.upsert(SemanticKeyframe {
            key: KeyframeKey {
                robot_id: format!("robot-{}", i % 4),
                session_id: "s".into(),
                keyframe_id: i as u64,
            },
            frame_id: 3 * i as u64,
            timestamp: i as f64,
            map_id: 0,
            pose: Pose::default(),
            features: features(&mut rng, dim, i),
        });
    }
    index
}

fn bench(c: &mut Criterion) {
    let params = VprParams::default();
    for (n, dim) in [(20_000, 512), (20_000, 1280)] {
        let index = index(n, dim);
        let mut rng = Rng(7);
        let history: Vec<Features> = (0..3).map(|p| features(&mut rng, dim, p)).collect();
        let refs: Vec<&Features> = history.iter().collect();
        let all = |_: usize| true;

        let mut group = c.benchmark_group(format!("query N={n} d={dim}"));
        group.sample_size(30);
        group.bench_function(BenchmarkId::from_parameter("baseline_dot_scan"), |b| {
            b.iter(|| {
                let m = index.descriptors();
                let q = &history[0].descriptor;
                let mut best = f32::MIN;
                for row in 0..m.len() {
                    best = best.max(humem_core::engine::matrix::dot(q, &m.row(row)));
                }
                black_box(best)
            })
        });
        group.bench_function(BenchmarkId::from_parameter("scal"), |b| {
            let query = ScalQuery {
                history: refs.clone(),
            };
            b.iter(|| black_box(vpr::scan::scal_scores(&params, &query, &index, &all)))
        });
        group.bench_function(BenchmarkId::from_parameter("rank_full"), |b| {
            let query = QueryObservation {
                history: refs.clone(),
            };
            b.iter(|| black_box(vpr::rank::rank(&params, Layers::FULL, &query, &index, &all)))
        });
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
