//! ROS bags without ROS: ROS 2 bags (MCAP or SQLite) and ROS 1 `.bag`
//! files, whose messages [`crate::bag_storage`] streams.
//!
//! A bag is read twice: first the poses, the TF tree, the camera's
//! intrinsics and every image's time and frame (only the image headers
//! are decoded), then, once the keyframes are chosen, only the keyframes'
//! images. A bag many times the memory is read in two streams and never
//! held whole.
//!
//! Poses are the camera's, as the folder form holds them: the pose of
//! `--tf-frames PARENT,CHILD` composed through the TF tree at each image's
//! time ([`crate::tf_tree`]), or a pose topic's, moved from the body it
//! tracks (an odometry's `child_frame_id`) to the images' frame by the
//! camera's mounting on `/tf_static` when the bag holds one.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use crate::align::{plan, sort_poses, Plan};
use crate::bag_storage::for_each_message;
use crate::error::RecordingError;
use crate::extraction::{Format, Options, Summary};
use crate::messages::{self, CameraInfo, Dialect, RawImage};
use crate::output::{FrameImage, LoopFolder};
use crate::pose::TimedPose;
use crate::tf_tree::TfTree;

/// The message types read.
const IMAGE: &str = "sensor_msgs/Image";
const COMPRESSED: &str = "sensor_msgs/CompressedImage";
const ODOMETRY: &str = "nav_msgs/Odometry";
const POSE_STAMPED: &str = "geometry_msgs/PoseStamped";
const TF: &str = "tf2_msgs/TFMessage";
const CAMERA_INFO: &str = "sensor_msgs/CameraInfo";

/// What the first pass found.
#[derive(Default)]
struct Survey {
    /// Topic → (type, messages).
    topics: BTreeMap<String, (String, usize)>,
    /// Image topic → image times, in message order.
    image_times: HashMap<String, Vec<f64>>,
    /// Image topic → the frame of its first image (the camera's).
    image_frames: HashMap<String, String>,
    /// Pose topic → poses.
    poses: HashMap<String, Vec<TimedPose>>,
    /// Odometry topic → the frame its poses are of (the body's).
    pose_bodies: HashMap<String, String>,
    /// CameraInfo topic → its first message.
    camera_infos: BTreeMap<String, CameraInfo>,
    /// Every transform on `/tf` and `/tf_static`.
    tf: TfTree,
}

/// Where the keyframes come from, as the first pass decided.
struct Sources {
    image_topic: String,
    /// Where the poses came from, for the summary.
    pose_source: String,
    poses: Vec<TimedPose>,
    /// The camera's intrinsics and the topic they came from.
    camera: Option<(String, CameraInfo)>,
}

impl Survey {
    fn listing(&self) -> String {
        self.topics
            .iter()
            .map(|(topic, (datatype, n))| format!("{topic} ({datatype}, {n})"))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The topic for `role` (`image`, `pose`): the one `asked` for, which
    /// must carry one of `types`, else the bag's only topic of those types;
    /// or why there is none (`none` when the bag has no such topic).
    fn choose(
        &self,
        asked: Option<&String>,
        role: &str,
        types: [&str; 2],
        flag: &str,
        none: &str,
    ) -> Result<String, String> {
        match asked {
            Some(topic) => match self.topics.get(topic) {
                Some((t, _)) if types.contains(&t.as_str()) => Ok(topic.clone()),
                Some((t, _)) => Err(format!(
                    "{role} topic {topic} carries {t}, not {} or {}",
                    types[0], types[1]
                )),
                None => Err(format!("no topic {topic}")),
            },
            None => match self.of_types(&types).as_slice() {
                [one] => Ok((*one).clone()),
                [] => Err(none.to_string()),
                many => Err(format!(
                    "{} {role} topics; name one with {flag}",
                    many.len()
                )),
            },
        }
    }

    /// The image topic, the poses (the asked chain of `/tf`, else the pose
    /// topic's, moved from the body to the camera where the tree holds the
    /// camera's mounting) and the camera's intrinsics. Errors list the
    /// bag's topics.
    fn sources(&mut self, path: &Path, options: &Options) -> Result<Sources, RecordingError> {
        let topic_error = |survey: &Survey, reason: String| RecordingError::Topic {
            path: path.to_path_buf(),
            reason,
            topics: survey.listing(),
        };
        let image_topic = self
            .choose(
                options.image_topic.as_ref(),
                "image",
                [IMAGE, COMPRESSED],
                "--image-topic",
                "no image topic",
            )
            .map_err(|reason| topic_error(self, reason))?;
        let camera = self.camera_info_for(&image_topic);
        if let Some((parent, child)) = &options.tf_frames {
            let chain = self.tf.chain(parent, child).map_err(|reason| {
                topic_error(self, format!("--tf-frames {parent},{child}: {reason}"))
            })?;
            let poses = self
                .image_times
                .get(&image_topic)
                .into_iter()
                .flatten()
                .filter_map(|&time| {
                    chain
                        .pose_at(time, options.pose_tolerance)
                        .map(|pose| TimedPose { time, pose })
                })
                .collect();
            return Ok(Sources {
                pose_source: format!("/tf {}", chain.describe()),
                image_topic,
                poses,
                camera,
            });
        }
        let topic = self
            .choose(
                options.pose_topic.as_ref(),
                "pose",
                [ODOMETRY, POSE_STAMPED],
                "--pose-topic",
                "no pose topic (nav_msgs/Odometry or geometry_msgs/PoseStamped); \
                 for poses on /tf name the frames with --tf-frames",
            )
            .map_err(|reason| topic_error(self, reason))?;
        let mut poses = self.poses.remove(&topic).unwrap_or_default();
        let mut pose_source = topic.clone();
        let body = self.pose_bodies.get(&topic).filter(|b| !b.is_empty());
        let lens = self
            .image_frames
            .get(&image_topic)
            .filter(|c| !c.is_empty());
        if let (Some(body), Some(lens)) = (body, lens) {
            if body.trim_start_matches('/') != lens.trim_start_matches('/') {
                match self.tf.chain(body, lens) {
                    Ok(mounting) => {
                        poses = poses
                            .into_iter()
                            .filter_map(|p| {
                                let m = mounting.pose_at(p.time, options.pose_tolerance)?;
                                Some(TimedPose {
                                    time: p.time,
                                    pose: p.pose.compose(&m),
                                })
                            })
                            .collect();
                        pose_source = format!(
                            "{topic}, moved to the camera by {} from {}",
                            mounting.describe(),
                            if mounting.is_static() {
                                "/tf_static"
                            } else {
                                "/tf"
                            }
                        );
                    }
                    Err(reason) => {
                        pose_source = format!(
                            "{topic}: the pose of {body}, not of the camera's frame {lens} ({reason})"
                        );
                    }
                }
            }
        }
        Ok(Sources {
            image_topic,
            pose_source,
            poses,
            camera,
        })
    }

    /// The `sensor_msgs/CameraInfo` of the camera behind `image_topic`:
    /// the bag's only one, else the one whose topic shares the most of the
    /// image topic's namespace and whose frame is the images' (when one
    /// alone does).
    fn camera_info_for(&self, image_topic: &str) -> Option<(String, CameraInfo)> {
        let frame = self.image_frames.get(image_topic);
        let shared = |topic: &str| {
            topic
                .split('/')
                .zip(image_topic.split('/'))
                .take_while(|(a, b)| a == b)
                .count()
        };
        let score = |(topic, info): (&String, &CameraInfo)| {
            (shared(topic), Some(&info.header.frame_id) == frame)
        };
        let best = self.camera_infos.iter().map(score).max()?;
        let mut chosen = self.camera_infos.iter().filter(|c| score(*c) == best);
        let (topic, info) = chosen.next()?;
        chosen
            .next()
            .is_none()
            .then(|| (topic.clone(), info.clone()))
    }

    fn of_types(&self, types: &[&str]) -> Vec<&String> {
        self.topics
            .iter()
            .filter(|(_, (t, _))| types.contains(&t.as_str()))
            .map(|(topic, _)| topic)
            .collect()
    }
}

/// A message's stamp: its header's, or the bag's log time when the
/// header's is zero.
fn stamp(header: f64, log_time: f64) -> f64 {
    if header > 0.0 {
        header
    } else {
        log_time
    }
}

/// Reads a bag into a `loop` folder at `out` (see [`crate::extract`]).
pub fn extract(
    path: &Path,
    format: Format,
    options: &Options,
    out: &Path,
) -> Result<Summary, RecordingError> {
    let dialect = match format {
        Format::Ros1Bag => Dialect::Ros1,
        _ => Dialect::Cdr,
    };
    let mut survey = survey(path, format, dialect)?;
    let mut sources = survey.sources(path, options)?;
    sort_poses(&mut sources.poses);
    let times = survey
        .image_times
        .remove(&sources.image_topic)
        .unwrap_or_default();
    let plan = plan(
        &times,
        &sources.poses,
        options.pose_tolerance,
        &options.keyframes,
        &sources.image_topic,
        &sources.pose_source,
    )?;
    let keyframes = write_keyframes(path, format, dialect, &sources, &plan, out)?;
    Ok(Summary {
        format,
        image_source: sources.image_topic,
        pose_source: sources.pose_source,
        calibration_source: sources.camera.map(|(topic, _)| topic),
        images: plan.images,
        without_pose: plan.without_pose,
        keyframes,
    })
}

/// A message that cannot be used: message `index` of `topic` in the bag
/// at `path`.
fn message_error(path: &Path, topic: &str, index: usize, reason: String) -> RecordingError {
    RecordingError::Message {
        path: path.to_path_buf(),
        topic: topic.to_string(),
        index,
        reason,
    }
}

/// Pass 1: every topic with its type and count, the image times and
/// frames, the poses of every pose topic, the camera intrinsics and the
/// TF tree.
fn survey(path: &Path, format: Format, dialect: Dialect) -> Result<Survey, RecordingError> {
    let mut survey = Survey::default();
    for_each_message(path, format, &mut |m| {
        let entry = survey
            .topics
            .entry(m.topic.to_string())
            .or_insert_with(|| (m.datatype.to_string(), 0));
        let index = entry.1;
        entry.1 += 1;
        let bad = |e: messages::MessageError| {
            message_error(path, m.topic, index, format!("{} {e}", m.datatype))
        };
        match m.datatype {
            IMAGE | COMPRESSED => {
                // The header leads both types.
                let header = messages::header(m.data, dialect).map_err(bad)?;
                survey
                    .image_times
                    .entry(m.topic.to_string())
                    .or_default()
                    .push(stamp(header.stamp, m.log_time));
                survey
                    .image_frames
                    .entry(m.topic.to_string())
                    .or_insert(header.frame_id);
            }
            CAMERA_INFO if !survey.camera_infos.contains_key(m.topic) => {
                let info = messages::camera_info(m.data, dialect).map_err(bad)?;
                survey.camera_infos.insert(m.topic.to_string(), info);
            }
            ODOMETRY | POSE_STAMPED => {
                let p = if m.datatype == ODOMETRY {
                    messages::odometry(m.data, dialect)
                } else {
                    messages::pose_stamped(m.data, dialect)
                }
                .map_err(bad)?;
                survey
                    .poses
                    .entry(m.topic.to_string())
                    .or_default()
                    .push(TimedPose {
                        time: stamp(p.header.stamp, m.log_time),
                        pose: p.pose,
                    });
                if m.datatype == ODOMETRY {
                    survey
                        .pose_bodies
                        .entry(m.topic.to_string())
                        .or_insert(p.child_frame_id);
                }
            }
            TF => {
                let is_static = m.topic.ends_with("tf_static");
                for t in messages::tf_message(m.data, dialect).map_err(bad)? {
                    survey.tf.add(
                        &t.header.frame_id,
                        &t.child_frame_id,
                        stamp(t.header.stamp, m.log_time),
                        t.pose,
                        is_static,
                    );
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    survey.tf.sort();
    Ok(survey)
}

/// Pass 2: the keyframes' images of `image_topic`, written in time order
/// into a new `loop` folder at `out`. Gives the number written.
fn write_keyframes(
    path: &Path,
    format: Format,
    dialect: Dialect,
    sources: &Sources,
    plan: &Plan,
    out: &Path,
) -> Result<usize, RecordingError> {
    let image_topic = sources.image_topic.as_str();
    let wanted: HashMap<usize, usize> = plan
        .keyframes
        .iter()
        .enumerate()
        .map(|(k, &(index, _, _))| (index, k))
        .collect();
    let mut folder = LoopFolder::create(out)?;
    if let Some((topic, info)) = &sources.camera {
        folder.set_calibration(info, &format!("{topic} in {}", path.display()));
    }
    let mut waiting: HashMap<usize, FrameImage> = HashMap::new();
    let mut index = 0;
    for_each_message(path, format, &mut |m| {
        if m.topic != image_topic {
            return Ok(());
        }
        let here = index;
        index += 1;
        let Some(&k) = wanted.get(&here) else {
            return Ok(());
        };
        let image = frame_image(m.datatype, m.data, dialect)
            .map_err(|reason| message_error(path, m.topic, here, reason))?;
        waiting.insert(k, image);
        while let Some(image) = waiting.remove(&folder.len()) {
            let (_, time, pose) = plan.keyframes[folder.len()];
            folder.push(time, &pose, image)?;
        }
        Ok(())
    })?;
    if folder.len() != plan.keyframes.len() {
        return Err(RecordingError::Damaged {
            path: path.to_path_buf(),
            reason: format!(
                "{image_topic} held {} images on the first read and fewer on the second",
                plan.images
            ),
        });
    }
    folder.finish()
}

/// A keyframe's image from its message: compressed bytes as they are,
/// raw pixels as an image.
fn frame_image(datatype: &str, data: &[u8], dialect: Dialect) -> Result<FrameImage, String> {
    if datatype == COMPRESSED {
        let m =
            messages::compressed_image(data, dialect).map_err(|e| format!("{COMPRESSED} {e}"))?;
        let format = m.format.to_ascii_lowercase();
        let ext = if format.contains("png") {
            "png"
        } else if format.contains("jpeg") || format.contains("jpg") {
            "jpg"
        } else {
            return Err(format!(
                "compressed format {:?} is not JPEG or PNG",
                m.format
            ));
        };
        return Ok(FrameImage::Encoded(m.data, ext));
    }
    let m = messages::image(data, dialect).map_err(|e| format!("{IMAGE} {e}"))?;
    pixels(&m).map(FrameImage::Pixels)
}

/// Decodes a `sensor_msgs/Image`'s pixels: 8-bit RGB, BGR, RGBA, BGRA and
/// mono, and 16-bit mono (scaled to 8 bits).
fn pixels(m: &RawImage) -> Result<image::DynamicImage, String> {
    let (w, h, step) = (m.width as usize, m.height as usize, m.step as usize);
    let channels = match m.encoding.as_str() {
        "rgb8" | "bgr8" | "8UC3" => 3,
        "rgba8" | "bgra8" | "8UC4" => 4,
        "mono8" | "8UC1" => 1,
        "mono16" | "16UC1" => 2,
        other => {
            return Err(format!(
                "unsupported encoding {other:?} (rgb8, bgr8, rgba8, bgra8, mono8, mono16 are read)"
            ))
        }
    };
    if w == 0 || h == 0 || step < w * channels || m.data.len() < step * (h - 1) + w * channels {
        return Err(format!(
            "{}x{} {} with step {} needs {} bytes, has {}",
            w,
            h,
            m.encoding,
            step,
            step * h,
            m.data.len()
        ));
    }
    let row = |y: usize| &m.data[y * step..y * step + w * channels];
    let mut rgb = Vec::with_capacity(w * h * 3);
    let mut grey = Vec::with_capacity(w * h);
    for y in 0..h {
        for px in row(y).chunks_exact(channels) {
            match m.encoding.as_str() {
                "rgb8" | "rgba8" => rgb.extend_from_slice(&px[..3]),
                "bgr8" | "bgra8" | "8UC3" | "8UC4" => rgb.extend_from_slice(&[px[2], px[1], px[0]]),
                "mono8" | "8UC1" => grey.push(px[0]),
                _ => {
                    let v = if m.big_endian {
                        u16::from_be_bytes([px[0], px[1]])
                    } else {
                        u16::from_le_bytes([px[0], px[1]])
                    };
                    grey.push((v >> 8) as u8);
                }
            }
        }
    }
    Ok(if channels >= 3 {
        image::DynamicImage::ImageRgb8(
            image::RgbImage::from_raw(m.width, m.height, rgb).expect("sized above"),
        )
    } else {
        image::DynamicImage::ImageLuma8(
            image::GrayImage::from_raw(m.width, m.height, grey).expect("sized above"),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::tests::Writer;

    fn raw(encoding: &str, w: u32, h: u32, step: u32, data: Vec<u8>) -> RawImage {
        RawImage {
            header: messages::Header {
                stamp: 0.0,
                frame_id: String::new(),
            },
            height: h,
            width: w,
            encoding: encoding.into(),
            big_endian: false,
            step,
            data,
        }
    }

    #[test]
    fn raw_pixels_decode_by_their_encoding_and_step() {
        // 2x1 BGR with a padded row of 8 bytes.
        let img = pixels(&raw("bgr8", 2, 1, 8, vec![1, 2, 3, 4, 5, 6, 0, 0])).unwrap();
        assert_eq!(img.to_rgb8().into_raw(), vec![3, 2, 1, 6, 5, 4]);
        let img = pixels(&raw("mono16", 1, 1, 2, vec![0x34, 0x12])).unwrap();
        assert_eq!(img.to_luma8().into_raw(), vec![0x12]);
        let err = pixels(&raw("yuv422", 1, 1, 2, vec![0; 2])).unwrap_err();
        assert!(err.contains("yuv422"), "{err}");
        let err = pixels(&raw("rgb8", 2, 2, 6, vec![0; 7])).unwrap_err();
        assert!(err.contains("needs 12 bytes, has 7"), "{err}");
    }

    #[test]
    fn compressed_images_keep_their_bytes_and_say_their_format() {
        let mut w = Writer::new(Dialect::Cdr);
        w.header(1, 0, "cam");
        w.string("rgb8; jpeg compressed bgr8");
        w.bytes(&[0xff, 0xd8, 0xff]);
        match frame_image(COMPRESSED, &w.data, Dialect::Cdr).unwrap() {
            FrameImage::Encoded(bytes, ext) => {
                assert_eq!(bytes, vec![0xff, 0xd8, 0xff]);
                assert_eq!(ext, "jpg");
            }
            _ => panic!("not kept encoded"),
        }
        let mut w = Writer::new(Dialect::Cdr);
        w.header(1, 0, "cam");
        w.string("tiff");
        w.bytes(&[1]);
        assert!(frame_image(COMPRESSED, &w.data, Dialect::Cdr)
            .err()
            .unwrap()
            .contains("tiff"));
    }
}
