//! A bag's TF tree: every transform on `/tf` and `/tf_static`, composed
//! into the pose of one frame in another at any time, as `tf2` looks one
//! up.
//!
//! A robot publishes its frames as a tree of edges (`map → odom →
//! base_link → camera_optical`), each from its own source at its own
//! rate: localisation a few times a second, odometry at 50 Hz, the camera's
//! mounting once on `/tf_static`. The camera's pose in the map at an
//! image's time is the product of the edges between the two frames, each
//! taken at that time: a dynamic edge interpolated between its samples
//! either side (position linearly, orientation by slerp, whatever the gap,
//! as `tf2` does), or the nearest one within the tolerance at either end of
//! its span; a static edge as it was last published. The chain runs up
//! from both frames to their nearest common ancestor, so any two frames of
//! one tree are joined, in either direction.
//!
//! Only the edges are kept (a few hundred bytes a second of a drive), so a
//! whole bag's tree fits in memory while its images stream past.

use std::collections::{BTreeMap, BTreeSet};

use crate::pose::{Pose, TimedPose};

/// Frame names as `tf2` compares them: without a leading `/`.
fn frame_name(frame: &str) -> &str {
    frame.trim_start_matches('/')
}

/// One edge: a child frame's pose in its parent's.
#[derive(Debug, Default)]
struct Edge {
    parent: String,
    /// Samples from `/tf`, sorted by time once the bag is read.
    dynamic: Vec<TimedPose>,
    /// The last value from `/tf_static`.
    fixed: Option<Pose>,
    /// Other parents this child was given (a tree has one).
    other_parents: BTreeSet<String>,
}

/// Every edge of a bag's TF tree.
#[derive(Debug, Default)]
pub struct TfTree {
    /// Child frame → its edge.
    edges: BTreeMap<String, Edge>,
}

impl TfTree {
    /// Adds a transform: `pose` of `child` in `parent` at `time` (seconds),
    /// from `/tf_static` when `is_static`.
    pub fn add(&mut self, parent: &str, child: &str, time: f64, pose: Pose, is_static: bool) {
        let (parent, child) = (frame_name(parent), frame_name(child));
        let edge = self.edges.entry(child.to_string()).or_insert_with(|| Edge {
            parent: parent.to_string(),
            ..Edge::default()
        });
        if edge.parent != parent {
            edge.other_parents.insert(parent.to_string());
            return;
        }
        if is_static {
            edge.fixed = Some(pose);
        } else {
            edge.dynamic.push(TimedPose { time, pose });
        }
    }

    /// Sorts every edge's samples by time; call once all are added.
    pub fn sort(&mut self) {
        for edge in self.edges.values_mut() {
            crate::align::sort_poses(&mut edge.dynamic);
        }
    }

    /// Whether the tree has no edge.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// Every frame named, for error messages.
    pub fn frames(&self) -> String {
        let mut frames: BTreeSet<&str> = BTreeSet::new();
        for (child, edge) in &self.edges {
            frames.insert(child);
            frames.insert(&edge.parent);
        }
        if frames.is_empty() {
            return "none (no /tf or /tf_static messages)".into();
        }
        frames.into_iter().collect::<Vec<_>>().join(", ")
    }

    /// `frame` and its ancestors up to the root, nearest first.
    fn lineage<'a>(&'a self, frame: &'a str) -> Result<Vec<&'a str>, String> {
        let mut line = vec![frame];
        let mut at = frame;
        while let Some(edge) = self.edges.get(at) {
            if let Some(other) = edge.other_parents.first() {
                return Err(format!(
                    "frame {at} has two parents on /tf, {} and {other}; a TF tree gives each frame one",
                    edge.parent
                ));
            }
            at = &edge.parent;
            if line.contains(&at) {
                return Err(format!("the TF tree has a cycle through {at}"));
            }
            line.push(at);
        }
        Ok(line)
    }

    /// The chain that gives `child`'s pose in `parent`, or why there is
    /// none (naming the tree's frames).
    pub fn chain(&self, parent: &str, child: &str) -> Result<Chain<'_>, String> {
        let (parent, child) = (frame_name(parent), frame_name(child));
        let known = |frame: &str| {
            self.edges.contains_key(frame) || self.edges.values().any(|e| e.parent == frame)
        };
        for frame in [parent, child] {
            if !known(frame) {
                return Err(format!(
                    "no frame {frame} on /tf or /tf_static; the frames there: {}",
                    self.frames()
                ));
            }
        }
        let from_child = self.lineage(child)?;
        let from_parent = self.lineage(parent)?;
        let Some(common) = from_child.iter().position(|f| from_parent.contains(f)) else {
            return Err(format!(
                "{parent} and {child} are in different TF trees (rooted at {} and {}); the frames: {}",
                from_parent.last().expect("a lineage holds its frame"),
                from_child.last().expect("a lineage holds its frame"),
                self.frames()
            ));
        };
        let ancestor = from_child[common];
        let up_to = |line: &[&str]| -> Vec<&Edge> {
            line.iter()
                .take_while(|f| **f != ancestor)
                .map(|f| &self.edges[*f])
                .collect()
        };
        let mut frames: Vec<&str> = from_parent
            .iter()
            .take_while(|f| **f != ancestor)
            .copied()
            .collect();
        frames.push(ancestor);
        frames.extend(from_child[..common].iter().rev());
        Ok(Chain {
            down_to_child: up_to(&from_child),
            down_to_parent: up_to(&from_parent),
            frames: frames.into_iter().map(String::from).collect(),
        })
    }
}

/// The edges between two frames of a [`TfTree`].
pub struct Chain<'a> {
    /// From the child up to the common ancestor.
    down_to_child: Vec<&'a Edge>,
    /// From the parent up to the common ancestor.
    down_to_parent: Vec<&'a Edge>,
    /// The frames passed, from the parent to the child.
    pub frames: Vec<String>,
}

impl Chain<'_> {
    /// Whether every edge of the chain is static (a fixed mounting).
    pub fn is_static(&self) -> bool {
        self.down_to_child
            .iter()
            .chain(&self.down_to_parent)
            .all(|e| e.dynamic.is_empty())
    }

    /// The frames passed, `a -> b -> c`.
    pub fn describe(&self) -> String {
        self.frames.join(" -> ")
    }

    /// The child's pose in the parent at `time`, or `None` when an edge
    /// has no value then (no sample either side, none within
    /// `tolerance` beyond its span).
    pub fn pose_at(&self, time: f64, tolerance: f64) -> Option<Pose> {
        let from_ancestor = |edges: &[&Edge]| -> Option<Pose> {
            let mut pose = Pose::identity();
            for edge in edges {
                pose = edge_at(edge, time, tolerance)?.compose(&pose);
            }
            Some(pose)
        };
        let child = from_ancestor(&self.down_to_child)?;
        let parent = from_ancestor(&self.down_to_parent)?;
        Some(parent.inverse().compose(&child))
    }
}

/// An edge's value at `time`.
fn edge_at(edge: &Edge, time: f64, tolerance: f64) -> Option<Pose> {
    let samples = &edge.dynamic;
    if samples.is_empty() {
        return edge.fixed;
    }
    let after = samples.partition_point(|p| p.time < time);
    match (
        after.checked_sub(1).map(|i| &samples[i]),
        samples.get(after),
    ) {
        (_, Some(b)) if b.time == time => Some(b.pose),
        (Some(a), Some(b)) => Some(
            a.pose
                .interpolate(&b.pose, (time - a.time) / (b.time - a.time)),
        ),
        (Some(a), None) if time - a.time <= tolerance => Some(a.pose),
        (None, Some(b)) if b.time - time <= tolerance => Some(b.pose),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    fn pose(x: f64, y: f64, yaw_deg: f64) -> Pose {
        Pose {
            t: Vector3::new(x, y, 0.0),
            r: UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
        }
    }

    fn close(a: &Pose, b: &Pose) -> bool {
        (a.t - b.t).norm() < 1e-9 && a.r.angle_to(&b.r) < 1e-9
    }

    /// map → odom (dynamic, 1 Hz), odom → base (dynamic, 10 Hz), base →
    /// camera (static), base → lidar (static).
    fn robot() -> TfTree {
        let mut tree = TfTree::default();
        for s in 0..=3 {
            tree.add("map", "odom", s as f64, pose(10.0, 0.0, 90.0), false);
        }
        for k in 0..=30 {
            let t = k as f64 * 0.1;
            tree.add("/odom", "base_link", t, pose(t, 0.0, 0.0), false);
        }
        tree.add("base_link", "camera", 0.0, pose(0.5, 0.0, -90.0), true);
        tree.add("base_link", "lidar", 0.0, pose(0.0, 0.2, 0.0), true);
        tree.sort();
        tree
    }

    #[test]
    fn a_chain_composes_static_and_dynamic_edges_at_the_time_asked() {
        let tree = robot();
        let chain = tree.chain("map", "camera").unwrap();
        assert_eq!(chain.describe(), "map -> odom -> base_link -> camera");
        assert!(!chain.is_static());
        // At 1.25 s the base is at x = 1.25 in odom (interpolated between
        // 1.2 and 1.3); odom is turned 90° in map, so the camera, 0.5 m
        // ahead of the base, is at (10, 1.75) facing 0°.
        let p = chain.pose_at(1.25, 0.0).unwrap();
        assert!(close(&p, &pose(10.0, 1.75, 0.0)), "{p:?}");
        // The same from the other end is the inverse.
        let back = tree.chain("camera", "map").unwrap().pose_at(1.25, 0.0);
        assert!(close(&back.unwrap(), &p.inverse()));
        // Across branches: the lidar seen from the camera, fixed.
        let across = tree.chain("camera", "lidar").unwrap();
        assert_eq!(across.describe(), "camera -> base_link -> lidar");
        assert!(across.is_static());
        let p = across.pose_at(99.0, 0.0).unwrap();
        let expected = pose(0.5, 0.0, -90.0)
            .inverse()
            .compose(&pose(0.0, 0.2, 0.0));
        assert!(close(&p, &expected));
    }

    #[test]
    fn a_time_past_a_dynamic_edge_needs_the_tolerance() {
        let tree = robot();
        let chain = tree.chain("map", "camera").unwrap();
        assert!(chain.pose_at(3.05, 0.0).is_none());
        assert!(chain.pose_at(3.05, 0.1).is_some());
        assert!(chain.pose_at(-0.2, 0.1).is_none());
    }

    #[test]
    fn frames_that_do_not_join_are_named() {
        let mut tree = robot();
        tree.add("world", "gps", 0.0, pose(0.0, 0.0, 0.0), true);
        let err = tree.chain("map", "gps").err().unwrap();
        assert!(
            err.contains("different TF trees (rooted at map and world)"),
            "{err}"
        );
        let err = tree.chain("map", "camera_optical").err().unwrap();
        assert!(err.contains("no frame camera_optical"), "{err}");
        assert!(
            err.contains("base_link, camera, gps, lidar, map, odom, world"),
            "{err}"
        );
        tree.add("map", "base_link", 0.0, pose(0.0, 0.0, 0.0), false);
        let err = tree.chain("map", "camera").err().unwrap();
        assert!(
            err.contains("base_link has two parents on /tf, odom and map"),
            "{err}"
        );
    }
}
