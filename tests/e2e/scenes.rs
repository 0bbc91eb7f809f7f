//! Synthetic worlds for the end-to-end tests: places with distinct global
//! descriptors, revisited with observation noise, so that the right answer
//! of every query is known.

use humem_server::proto;

/// Descriptor length used by the tests.
pub const DIM: usize = 64;

/// SplitMix64: a small deterministic generator, so every run sees the same world.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f32 {
        let u1 = self.uniform().max(1e-7);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
    }
}

fn normalised(mut v: Vec<f32>) -> Vec<f32> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.iter_mut().for_each(|x| *x /= n);
    v
}

/// Places, each with its own appearance.
pub struct World {
    places: Vec<Vec<f32>>,
    rng: Rng,
}

impl World {
    pub fn new(places: usize, seed: u64) -> World {
        let mut rng = Rng::new(seed);
        let places = (0..places)
            .map(|_| normalised((0..DIM).map(|_| rng.normal()).collect()))
            .collect();
        World { places, rng }
    }

    /// A view of `place`: its appearance plus noise of relative size `noise`.
    pub fn view(&mut self, place: usize, noise: f32) -> Vec<f32> {
        let scale = noise / (DIM as f32).sqrt();
        let v = self.places[place]
            .iter()
            .map(|x| x + scale * self.rng.normal())
            .collect();
        normalised(v)
    }
}

pub fn pose(x: f64) -> proto::Pose {
    proto::Pose {
        translation: Some(proto::Vec3 { x, y: 0.0, z: 0.0 }),
        rotation: Some(proto::Quaternion {
            w: 1.0,
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }),
    }
}

/// A sign with text on it.
pub fn sign(text: &str, x: f32, y: f32) -> proto::ObjectObservation {
    proto::ObjectObservation {
        class_name: "sign".into(),
        confidence: 0.9,
        x,
        y,
        area: 0.02,
        texts: vec![proto::TextObservation {
            text: text.into(),
            confidence: 0.95,
        }],
    }
}

/// Precomputed features: a descriptor, one scene class, objects.
pub fn features(
    descriptor: Vec<f32>,
    scene_class: u32,
    objects: Vec<proto::ObjectObservation>,
) -> proto::Features {
    proto::Features {
        global_descriptor: descriptor,
        scene: vec![proto::SceneClass {
            class_id: scene_class,
            probability: 0.6,
        }],
        objects,
        appearance: vec![],
    }
}

/// A keyframe of `robot`/`session` with ids `[keyframe, frame, map]`.
pub fn keyframe(
    robot: &str,
    session: &str,
    [keyframe_id, frame_id, map_id]: [u64; 3],
    features: proto::Features,
) -> proto::Keyframe {
    proto::Keyframe {
        robot_id: robot.into(),
        session_id: session.into(),
        keyframe_id: Some(keyframe_id),
        frame_id: Some(frame_id),
        timestamp: frame_id as f64 / 30.0,
        map_id: Some(map_id),
        pose: Some(pose(keyframe_id as f64)),
        content: Some(proto::keyframe::Content::Features(features)),
    }
}

/// A drive through `first_lap` places and back through the first
/// `second_lap` of them: keyframe `k` is made from frame `3 k` and stands
/// at its place's position (`x` = the place), so a revisit is where the
/// map put the first visit. Returns the keyframes and the place each
/// shows.
pub fn loop_drive(
    world: &mut World,
    robot: &str,
    session: &str,
    map_id: u64,
    first_lap: usize,
    second_lap: usize,
) -> Vec<(proto::Keyframe, usize)> {
    (0..first_lap)
        .chain(0..second_lap)
        .enumerate()
        .map(|(k, place)| {
            let text = format!("ROOM {}", 100 + place);
            let objects = vec![sign(&text, 0.2 + 0.006 * (place % 100) as f32, 0.3)];
            let mut kf = keyframe(
                robot,
                session,
                [k as u64, 3 * k as u64, map_id],
                features(world.view(place, 0.35), (place / 10) as u32, objects),
            );
            kf.pose = Some(pose(place as f64));
            (kf, place)
        })
        .collect()
}

/// The features a keyframe was sent with.
pub fn features_of(kf: &proto::Keyframe) -> proto::Features {
    match &kf.content {
        Some(proto::keyframe::Content::Features(f)) => f.clone(),
        _ => panic!("keyframe without features"),
    }
}

pub fn id(kf: &proto::Keyframe) -> u64 {
    kf.keyframe_id.unwrap()
}

/// Inserts keyframes in batches.
pub async fn insert_all(
    client: &mut proto::place_recognition_client::PlaceRecognitionClient<tonic::transport::Channel>,
    keyframes: impl IntoIterator<Item = proto::Keyframe>,
) {
    let keyframes: Vec<_> = keyframes.into_iter().collect();
    for chunk in keyframes.chunks(100) {
        client
            .insert_batch(proto::InsertBatchRequest {
                keyframes: chunk.to_vec(),
            })
            .await
            .expect("InsertBatch");
    }
}

/// A query for a stored keyframe, with everything else left to defaults.
pub fn query_stored(robot: &str, session: &str, keyframe_id: u64) -> proto::QueryRequest {
    proto::QueryRequest {
        robot_id: robot.into(),
        session_id: session.into(),
        keyframe_id: Some(keyframe_id),
        ..Default::default()
    }
}
