//! Test-only builders and proptest strategies shared by the layer tests.
//!
//! The property tests of OSRL, OGTL and ranking all need random objects with
//! a few classes, positions clustered enough that gates sometimes pass, and
//! OCR strings from a small vocabulary that contains near-duplicates; they
//! are defined once here.

use proptest::prelude::*;

use crate::keyframe::{Features, ObjectObservation, SceneClass, TextObservation};
use crate::vpr::eligibility::{MapRef, Scope};
use crate::vpr::memory::VecMemory;

/// Absolute-tolerance comparison for hand-computed expectations.
pub fn close(a: f32, b: f32) -> bool {
    (a - b).abs() < 1e-5
}

/// An object with the given class, confidence, centroid and area, no text.
pub fn object(class: &str, confidence: f32, x: f32, y: f32, area: f32) -> ObjectObservation {
    ObjectObservation {
        class_name: class.to_string(),
        confidence,
        centroid: [x, y],
        area,
        texts: Vec::new(),
    }
}

/// The same object carrying OCR strings `(text, confidence)`.
pub fn with_texts(mut o: ObjectObservation, texts: &[(&str, f32)]) -> ObjectObservation {
    o.texts = texts
        .iter()
        .map(|(t, p)| TextObservation {
            text: t.to_string(),
            confidence: *p,
        })
        .collect();
    o
}

/// Features with a descriptor, a scene distribution and objects.
pub fn features(
    descriptor: &[f32],
    scene: &[(u32, f32)],
    objects: Vec<ObjectObservation>,
) -> Features {
    Features {
        descriptor: descriptor.to_vec(),
        appearance: vec![],
        scene: scene
            .iter()
            .map(|&(class_id, probability)| SceneClass {
                class_id,
                probability,
            })
            .collect(),
        objects,
    }
}

const CLASSES: &[&str] = &["building", "sign", "fence"];
const VOCABULARY: &[&str] = &[
    "EXIT",
    "B-214",
    "b214",
    "Main St 5",
    "main street",
    "OPEN",
    "21 4",
    "Café Rouge",
    "cafe rouge 12",
];

pub fn text_strategy() -> impl Strategy<Value = TextObservation> {
    (prop::sample::select(VOCABULARY), 0.0f32..=1.0).prop_map(|(t, p)| TextObservation {
        text: t.to_string(),
        confidence: p,
    })
}

/// Objects in the central part of the image, so that `G` is often large.
pub fn object_strategy() -> impl Strategy<Value = ObjectObservation> {
    (
        prop::sample::select(CLASSES),
        0.0f32..=1.0,
        0.3f32..0.7,
        0.3f32..0.7,
        0.0f32..0.3,
        prop::collection::vec(text_strategy(), 0..3),
    )
        .prop_map(|(class, p, x, y, a, texts)| ObjectObservation {
            class_name: class.to_string(),
            confidence: p,
            centroid: [x, y],
            area: a,
            texts,
        })
}

pub fn objects_strategy(max: usize) -> impl Strategy<Value = Vec<ObjectObservation>> {
    prop::collection::vec(object_strategy(), 0..max)
}

/// A unit vector of dimension `dim` (or a fixed one when the draw is ~0).
pub fn unit_vector(dim: usize) -> impl Strategy<Value = Vec<f32>> {
    prop::collection::vec(-1.0f32..1.0, dim).prop_map(|v| {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        if n < 1e-3 {
            let mut e = vec![0.0; v.len()];
            e[0] = 1.0;
            e
        } else {
            v.iter().map(|x| x / n).collect()
        }
    })
}

/// Query features from `(descriptor, scene)` pairs, the rest default.
pub fn features_of(history: Vec<(Vec<f32>, Vec<SceneClass>)>) -> Vec<Features> {
    history
        .into_iter()
        .map(|(descriptor, scene)| Features {
            descriptor,
            scene,
            ..Features::default()
        })
        .collect()
}

/// A sparse scene distribution over a few class ids.
pub fn scene_strategy() -> impl Strategy<Value = Vec<SceneClass>> {
    prop::collection::btree_map(0u32..6, 0.0f32..1.0, 0..4).prop_map(|m| {
        let total: f32 = m.values().sum::<f32>().max(1e-6);
        m.into_iter()
            .map(|(class_id, p)| SceneClass {
                class_id,
                probability: p / total,
            })
            .collect()
    })
}

/// A random store of up to `max_rows` rows: unit descriptors of length
/// `dim`, random scene lists, and for each row a predecessor among the
/// earlier rows (or none).
pub fn memory_strategy(dim: usize, max_rows: usize) -> impl Strategy<Value = VecMemory> {
    prop::collection::vec(
        (
            unit_vector(dim),
            scene_strategy(),
            any::<prop::sample::Index>(),
            any::<bool>(),
        ),
        0..max_rows,
    )
    .prop_map(move |rows| {
        let mut m = VecMemory::new(dim);
        for (i, (descriptor, scene, pred, has_pred)) in rows.into_iter().enumerate() {
            let pred = (has_pred && i > 0).then(|| pred.index(i));
            m.push(
                Features {
                    descriptor,
                    scene,
                    ..Features::default()
                },
                pred,
            );
        }
        m
    })
}

/// A query scope over robots named from `robots` and sessions from
/// `sessions`: the three fixed scopes, or a list of up to two robots and
/// two maps (session named or any, map id 0..3).
pub fn scope_strategy(
    robots: &'static [&'static str],
    sessions: &'static [&'static str],
) -> impl Strategy<Value = Scope> {
    let name =
        |names: &'static [&'static str]| prop::sample::select(names).prop_map(str::to_string);
    let map = (name(robots), prop::option::of(name(sessions)), 0u64..3).prop_map(
        |(robot_id, session_id, map_id)| MapRef {
            robot_id,
            session_id,
            map_id,
        },
    );
    prop_oneof![
        Just(Scope::SameMap),
        Just(Scope::OtherMaps),
        Just(Scope::AllMaps),
        (
            prop::collection::vec(name(robots), 0..3),
            prop::collection::vec(map, 0..3)
        )
            .prop_map(|(robot_ids, maps)| Scope::Listed { robot_ids, maps }),
    ]
}
