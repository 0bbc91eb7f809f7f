//! ROS bags without ROS: ROS 2 bags in MCAP (a `.mcap` file or a rosbag2
//! folder of them) through the `mcap` crate's streaming reader, ROS 1
//! `.bag` files through the `rosbag` crate.
//!
//! Both readers hand each message (topic, type, log time, bytes) to the
//! same code, which reads a bag twice: first the poses and every image's
//! time (only the image headers are decoded), then, once the keyframes
//! are chosen, only the keyframes' images. A bag many times the memory
//! is read in two streams and never held whole.

use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::{Path, PathBuf};

use crate::align::{plan, sort_poses, Plan};
use crate::error::RecordingError;
use crate::extraction::{Format, Options, Summary};
use crate::messages::{self, Dialect, RawImage};
use crate::output::{FrameImage, LoopFolder};
use crate::pose::TimedPose;

/// One message of a bag.
struct BagMessage<'a> {
    topic: &'a str,
    /// The type without `/msg/`: `sensor_msgs/Image`.
    datatype: &'a str,
    /// Seconds.
    log_time: f64,
    data: &'a [u8],
}

/// The message types read.
const IMAGE: &str = "sensor_msgs/Image";
const COMPRESSED: &str = "sensor_msgs/CompressedImage";
const ODOMETRY: &str = "nav_msgs/Odometry";
const POSE_STAMPED: &str = "geometry_msgs/PoseStamped";
const TF: &str = "tf2_msgs/TFMessage";

/// `sensor_msgs/msg/Image` → `sensor_msgs/Image`.
fn ros1_name(datatype: &str) -> String {
    datatype.replacen("/msg/", "/", 1)
}

/// Calls `f` on every message of the bag at `path`, in file order.
fn for_each_message(
    path: &Path,
    format: Format,
    f: &mut dyn FnMut(BagMessage) -> Result<(), RecordingError>,
) -> Result<(), RecordingError> {
    match format {
        Format::Ros1Bag => ros1_messages(path, f),
        _ => {
            for file in mcap_files(path)? {
                mcap_messages(&file, f)?;
            }
            Ok(())
        }
    }
}

/// The MCAP files of a bag: the file itself, or a rosbag2 folder's
/// `.mcap` files in name order (a split bag).
fn mcap_files(path: &Path) -> Result<Vec<PathBuf>, RecordingError> {
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files = Vec::new();
    let mut sqlite = false;
    for entry in std::fs::read_dir(path).map_err(RecordingError::io(path))? {
        let entry = entry.map_err(RecordingError::io(path))?.path();
        match entry.extension().and_then(|e| e.to_str()) {
            Some("mcap") => files.push(entry),
            Some("db3") => sqlite = true,
            _ => {}
        }
    }
    files.sort();
    if files.is_empty() {
        return Err(RecordingError::UnknownFormat {
            path: path.to_path_buf(),
            reason: if sqlite {
                "a rosbag2 folder in SQLite storage (.db3); HuMem reads MCAP, \
                 the default since ROS 2 Iron: `ros2 bag convert` makes one"
                    .into()
            } else {
                "a rosbag2 folder without .mcap files".into()
            },
        });
    }
    Ok(files)
}

fn mcap_messages(
    path: &Path,
    f: &mut dyn FnMut(BagMessage) -> Result<(), RecordingError>,
) -> Result<(), RecordingError> {
    use mcap::records::Record;
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};
    let damaged = |reason: String| RecordingError::Damaged {
        path: path.to_path_buf(),
        reason,
    };
    let mut file = std::fs::File::open(path).map_err(RecordingError::io(path))?;
    let mut reader = LinearReader::new();
    let mut schemas: HashMap<u16, String> = HashMap::new();
    let mut channels: HashMap<u16, (String, String, String)> = HashMap::new();
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| damaged(e.to_string()))? {
            LinearReadEvent::ReadRequest(need) => {
                let read = file
                    .read(reader.insert(need))
                    .map_err(RecordingError::io(path))?;
                reader.notify_read(read);
            }
            LinearReadEvent::Record { opcode, data } => {
                match mcap::parse_record(opcode, data).map_err(|e| damaged(e.to_string()))? {
                    Record::Schema { header, .. } => {
                        schemas.insert(header.id, ros1_name(&header.name));
                    }
                    Record::Channel(channel) => {
                        let datatype = schemas.get(&channel.schema_id).cloned().unwrap_or_default();
                        channels.insert(
                            channel.id,
                            (channel.topic, datatype, channel.message_encoding),
                        );
                    }
                    Record::Message { header, data } => {
                        let Some((topic, datatype, encoding)) = channels.get(&header.channel_id)
                        else {
                            return Err(damaged(format!(
                                "a message on channel {} that no channel record announced",
                                header.channel_id
                            )));
                        };
                        if encoding != "cdr" {
                            continue;
                        }
                        f(BagMessage {
                            topic,
                            datatype,
                            log_time: header.log_time as f64 * 1e-9,
                            data: &data,
                        })?;
                    }
                    _ => {}
                }
            }
        }
    }
    Ok(())
}

fn ros1_messages(
    path: &Path,
    f: &mut dyn FnMut(BagMessage) -> Result<(), RecordingError>,
) -> Result<(), RecordingError> {
    use rosbag::{ChunkRecord, MessageRecord, RosBag};
    let damaged = |reason: String| RecordingError::Damaged {
        path: path.to_path_buf(),
        reason,
    };
    check_ros1_index(path)?;
    let bag = RosBag::new(path).map_err(|e| damaged(e.to_string()))?;
    let mut connections: HashMap<u32, (String, String)> = HashMap::new();
    for record in bag.chunk_records() {
        let ChunkRecord::Chunk(chunk) = record.map_err(|e| damaged(e.to_string()))? else {
            continue;
        };
        for message in chunk.messages() {
            match message.map_err(|e| damaged(e.to_string()))? {
                MessageRecord::Connection(c) => {
                    connections.insert(c.id, (c.topic.to_string(), c.tp.to_string()));
                }
                MessageRecord::MessageData(m) => {
                    let Some((topic, datatype)) = connections.get(&m.conn_id) else {
                        return Err(damaged(format!(
                            "a message on connection {} that no connection record announced",
                            m.conn_id
                        )));
                    };
                    // Bag time: seconds in the low 32 bits, nanoseconds above.
                    let log_time = (m.time & 0xffff_ffff) as f64 + (m.time >> 32) as f64 * 1e-9;
                    f(BagMessage {
                        topic,
                        datatype,
                        log_time,
                        data: m.data,
                    })?;
                }
            }
        }
    }
    Ok(())
}

/// Checks that a ROS 1 bag's index lies within the file: a bag cut short
/// (a copy interrupted, a recorder killed) has lost it, and the `rosbag`
/// crate would index past the end of its mapping.
fn check_ros1_index(path: &Path) -> Result<(), RecordingError> {
    let damaged = |reason: &str| RecordingError::Damaged {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    };
    let mut file = std::fs::File::open(path).map_err(RecordingError::io(path))?;
    let len = file.metadata().map_err(RecordingError::io(path))?.len();
    let mut head = vec![0u8; 4096.min(len as usize)];
    file.read_exact(&mut head)
        .map_err(RecordingError::io(path))?;
    const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
    let Some(rest) = head.strip_prefix(MAGIC) else {
        return Err(damaged("not a ROS 1 bag (no #ROSBAG V2.0 line)"));
    };
    // The bag header record: its header's length, then `len name=value`
    // fields; `index_pos` is where the index starts.
    let u32_at = |b: &[u8], at: usize| {
        b.get(at..at + 4)
            .map(|v| u32::from_le_bytes(v.try_into().expect("4")) as usize)
    };
    let header_len = u32_at(rest, 0).ok_or_else(|| damaged("cut inside its header"))?;
    let header = rest
        .get(4..4 + header_len)
        .ok_or_else(|| damaged("cut inside its header"))?;
    let mut at = 0;
    while let Some(field_len) = u32_at(header, at) {
        let field = header
            .get(at + 4..at + 4 + field_len)
            .ok_or_else(|| damaged("a bad header field"))?;
        if let Some(value) = field.strip_prefix(b"index_pos=") {
            let index_pos =
                u64::from_le_bytes(value.try_into().map_err(|_| damaged("a bad index_pos"))?);
            if index_pos == 0 || index_pos >= len {
                return Err(damaged(&format!(
                    "truncated or never closed: its index starts at byte {index_pos} of {len} \
                     (`rosbag reindex` can rebuild it)"
                )));
            }
            return Ok(());
        }
        at += 4 + field_len;
    }
    Err(damaged("its header has no index_pos"))
}

/// What the first pass found.
#[derive(Default)]
struct Survey {
    /// Topic → (type, messages).
    topics: BTreeMap<String, (String, usize)>,
    /// Image topic → image times, in message order.
    image_times: HashMap<String, Vec<f64>>,
    /// Pose topic → poses.
    poses: HashMap<String, Vec<TimedPose>>,
    /// Poses of the asked transform from `/tf` and `/tf_static`.
    tf_poses: Vec<TimedPose>,
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

    /// The image topic, and where the poses come from with the poses
    /// themselves (taken out of the survey): the asked transform of `/tf`,
    /// else the pose topic. Errors list the bag's topics.
    fn sources(
        &mut self,
        path: &Path,
        options: &Options,
    ) -> Result<(String, String, Vec<TimedPose>), RecordingError> {
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
        if let Some((parent, child)) = &options.tf_frames {
            if self.tf_poses.is_empty() {
                return Err(topic_error(self, format!(
                    "no transform from {parent} to {child} on /tf or /tf_static (only direct edges of the tree are read)"
                )));
            }
            let poses = std::mem::take(&mut self.tf_poses);
            return Ok((image_topic, format!("/tf {parent} -> {child}"), poses));
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
        let poses = self.poses.remove(&topic).unwrap_or_default();
        Ok((image_topic, topic, poses))
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
    let mut survey = survey(path, format, dialect, options)?;
    let (image_topic, pose_source, mut poses) = survey.sources(path, options)?;
    sort_poses(&mut poses);
    let times = survey.image_times.remove(&image_topic).unwrap_or_default();
    let plan = plan(
        &times,
        &poses,
        options.pose_tolerance,
        &options.keyframes,
        &image_topic,
        &pose_source,
    )?;
    let keyframes = write_keyframes(path, format, dialect, &image_topic, &plan, out)?;
    Ok(Summary {
        format,
        image_source: image_topic,
        pose_source,
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

/// Pass 1: every topic with its type and count, the image times, the
/// poses of every pose topic and of the asked transform.
fn survey(
    path: &Path,
    format: Format,
    dialect: Dialect,
    options: &Options,
) -> Result<Survey, RecordingError> {
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
                let header = messages::header_stamp(m.data, dialect).map_err(bad)?;
                survey
                    .image_times
                    .entry(m.topic.to_string())
                    .or_default()
                    .push(stamp(header, m.log_time));
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
            }
            TF => {
                if let Some((parent, child)) = &options.tf_frames {
                    for t in messages::tf_message(m.data, dialect).map_err(bad)? {
                        if t.header.frame_id.trim_start_matches('/')
                            == parent.trim_start_matches('/')
                            && t.child_frame_id.trim_start_matches('/')
                                == child.trim_start_matches('/')
                        {
                            survey.tf_poses.push(TimedPose {
                                time: stamp(t.header.stamp, m.log_time),
                                pose: t.pose,
                            });
                        }
                    }
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    Ok(survey)
}

/// Pass 2: the keyframes' images of `image_topic`, written in time order
/// into a new `loop` folder at `out`. Gives the number written.
fn write_keyframes(
    path: &Path,
    format: Format,
    dialect: Dialect,
    image_topic: &str,
    plan: &Plan,
    out: &Path,
) -> Result<usize, RecordingError> {
    let wanted: HashMap<usize, usize> = plan
        .keyframes
        .iter()
        .enumerate()
        .map(|(k, &(index, _, _))| (index, k))
        .collect();
    let mut folder = LoopFolder::create(out)?;
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
