//! `humem eval --source` on one drive written in every recording format:
//! a ROS 2 MCAP bag, a ROS 1 bag, TUM RGB-D, EuRoC and KITTI, and a ROS 2
//! bag laid out as a robot records one (the body's odometry at its own
//! rate, a TF tree with the camera's mounting on /tf_static, JPEG images
//! with their CameraInfo) in MCAP and in split SQLite storage, made at test
//! time from `town-dev/loop` by `tools/make_recordings.py` (with `rosbags`,
//! a writer independent of HuMem's readers). Each gives the folder form's
//! figures exactly; a damaged bag and a wrong topic get clear errors, and
//! nothing is left half-written.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::harness::{datasets, models_dir};

/// Every 4th frame of the loop: 105 keyframes; the gap scales with it.
const EVERY: &str = "4";
const MIN_GAP: &str = "25";

fn make_recordings(out: &Path) -> Option<PathBuf> {
    let datasets = datasets()?;
    let status = Command::new(models_dir().join(".venv/bin/python"))
        .arg(crate::harness::repo_root().join("tools/make_recordings.py"))
        .arg(datasets.join("town-dev/loop"))
        .arg(out)
        .args(["--every", EVERY])
        .status()
        .expect("running tools/make_recordings.py");
    assert!(status.success(), "tools/make_recordings.py failed");
    Some(out.to_path_buf())
}

fn humem_eval(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_humem"))
        .arg("eval")
        .args(args)
        .env("HUMEM_PERCEPTION__MODELS_DIR", models_dir())
        .env("RUST_BACKTRACE", "0")
        .env("RUST_LIB_BACKTRACE", "0")
        .output()
        .expect("running humem eval")
}

/// The run's figures: the JSON without the data set's name and the
/// timings, which are all that may differ between two forms of a drive.
fn figures(json: &Path) -> serde_json::Value {
    let mut value: serde_json::Value =
        serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap();
    value.as_object_mut().unwrap().remove("dataset");
    for condition in value["conditions"].as_array_mut().unwrap() {
        for result in condition["results"].as_array_mut().unwrap() {
            let result = result.as_object_mut().unwrap();
            result.remove("latency");
            result.remove("stages_ms");
        }
    }
    value
}

fn eval_figures(source: &[&str], extra: &[&str], out: &Path) -> serde_json::Value {
    let json = out.join("figures.json");
    let _ = std::fs::remove_file(&json);
    let mut args: Vec<&str> = source.to_vec();
    args.extend([
        "--all-queries",
        "--no-baseline",
        "--min-gap",
        MIN_GAP,
        "--json",
        json.to_str().unwrap(),
    ]);
    args.extend(extra);
    let output = humem_eval(&args);
    assert!(
        output.status.success(),
        "humem eval {args:?} failed:\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    figures(&json)
}

#[test]
fn every_recording_format_gives_the_folders_figures() {
    let dir = tempfile::tempdir().unwrap();
    let Some(recordings) = make_recordings(dir.path()) else {
        return;
    };
    let path = |name: &str| recordings.join(name).to_str().unwrap().to_string();
    let folder = eval_figures(&["--dataset", &path("folder")], &[], dir.path());
    let results = &folder["conditions"][0]["results"][0];
    assert_eq!(folder["references"], 105, "{folder}");
    assert!(results["queries"].as_u64().unwrap() > 20, "{folder}");
    assert!(results["recall_at_1"].as_f64().unwrap() > 0.5, "{folder}");

    let every_image = ["--keyframe-distance", "0", "--keyframe-angle", "0"];
    let sources: [(&str, &[&str]); 8] = [
        ("ros2", &["--pose-topic", "/odom"]),
        ("drive.bag", &["--tf-frames", "map,camera"]),
        ("tum", &[]),
        ("euroc", &[]),
        ("kitti", &[]),
        // The camera in the map through map -> odom -> base_link ->
        // camera_optical, and the body's odometry moved to the camera.
        ("robot", &["--tf-frames", "map,camera_optical"]),
        ("robot", &["--pose-topic", "/odom"]),
        ("robot_db3", &["--tf-frames", "map,camera_optical"]),
    ];
    for (name, options) in sources {
        let source = path(name);
        let mut extra: Vec<&str> = every_image.to_vec();
        extra.extend(options);
        let figures = eval_figures(&["--source", &source], &extra, dir.path());
        assert_eq!(
            figures, folder,
            "{name} {options:?} differs from the folder form"
        );
    }
    // The same bag's PoseStamped topic gives the same poses.
    let mut extra: Vec<&str> = every_image.to_vec();
    extra.extend(["--pose-topic", "/pose"]);
    let figures = eval_figures(&["--source", &path("ros2")], &extra, dir.path());
    assert_eq!(
        figures, folder,
        "ros2 with /pose differs from the folder form"
    );
}

/// The poses of a `sequence_poses.txt`: (position, quaternion x y z w).
fn poses(folder: &Path) -> Vec<[f64; 7]> {
    std::fs::read_to_string(folder.join("sequence_poses.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            v[1..8].try_into().unwrap()
        })
        .collect()
}

#[test]
fn a_robots_bag_gives_the_cameras_pose_in_the_map_and_its_intrinsics() {
    let dir = tempfile::tempdir().unwrap();
    let Some(recordings) = make_recordings(dir.path()) else {
        return;
    };
    let truth = poses(&recordings.join("folder"));
    for (name, options) in [
        ("robot", ["--tf-frames", "map,camera_optical"]),
        ("robot_db3", ["--tf-frames", "map,camera_optical"]),
        ("robot_db3", ["--pose-topic", "/odom"]),
    ] {
        let kept = dir.path().join(format!("kept-{name}-{}", &options[0][2..]));
        let output = humem_eval(&[
            "--source",
            recordings.join(name).to_str().unwrap(),
            options[0],
            options[1],
            "--keyframe-distance",
            "0",
            "--keyframe-angle",
            "0",
            "--keep-frames",
            kept.to_str().unwrap(),
            "--no-baseline",
            "--all-queries",
            "--min-gap",
            MIN_GAP,
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{name} {options:?}: {stderr}");
        let read = poses(&kept);
        assert_eq!(read.len(), truth.len(), "{name} {options:?}");
        // The map's poses within 10 cm and 1°: the drive's poses are
        // straight lines between 10 Hz frames, and the bag's odometry, at
        // 20 Hz 13 ms off the camera's clock, is interpolated at the
        // images' times, which cuts the corners of a turn by centimetres (a
        // wrong composition is metres off). The odometry's are the same
        // poses seen from where odometry started: distances are kept.
        let distance = |p: &[f64; 7], q: &[f64; 7]| {
            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
        };
        for (k, (a, b)) in read.iter().zip(&truth).enumerate() {
            let context = format!("{name} {options:?} keyframe {k}: {a:?} against {b:?}");
            if options[1] == "/odom" {
                let moved = distance(a, &read[0]) - distance(b, &truth[0]);
                assert!(moved.abs() < 0.1, "{context}");
            } else {
                assert!(distance(a, b) < 0.1, "{context}");
                let dot: f64 = (3..7).map(|i| a[i] * b[i]).sum();
                let degrees = 2.0 * dot.abs().min(1.0).acos().to_degrees();
                assert!(degrees < 1.0, "{context}: {degrees}°");
            }
        }
        let expected = if options[1] == "/odom" {
            "poses: /odom, moved to the camera by base_link -> camera_optical from /tf_static"
        } else {
            "poses: /tf map -> odom -> base_link -> camera_optical"
        };
        assert!(stderr.contains(expected), "{name} {options:?}: {stderr}");
        assert!(
            stderr.contains("intrinsics: /camera/camera_info"),
            "{stderr}"
        );
        let calib: serde_json::Value =
            serde_json::from_slice(&std::fs::read(kept.join("sequence_calib.json")).unwrap())
                .unwrap();
        assert_eq!(calib["width"], 512, "{calib}");
        assert_eq!(calib["height"], 288, "{calib}");
        assert_eq!(calib["fx"], 304.0, "{calib}");
        assert_eq!(calib["cy"], 144.0, "{calib}");
        assert_eq!(calib["camera_frame"], "camera_optical", "{calib}");
        assert_eq!(calib["distortion"]["k1"], 0.0, "{calib}");
    }

    // A frame the tree lacks: the tree's frames are named.
    let output = humem_eval(&[
        "--source",
        recordings.join("robot_db3").to_str().unwrap(),
        "--tf-frames",
        "map,camera",
    ]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(
        stderr.contains("no frame camera on /tf or /tf_static; the frames there: base_link, camera_optical, map, odom"),
        "{stderr}"
    );
}

#[test]
fn damaged_bags_and_wrong_topics_get_clear_errors_and_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let Some(recordings) = make_recordings(dir.path()) else {
        return;
    };
    let kept = dir.path().join("kept");
    let kept_arg = kept.to_str().unwrap().to_string();

    // Bags cut in half, as a copy interrupted would leave them.
    let mcap = std::fs::read_dir(recordings.join("ros2"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "mcap"))
        .unwrap();
    for (bag, name, options) in [
        (
            recordings.join("drive.bag"),
            "cut.bag",
            ["--tf-frames", "map,camera"],
        ),
        (mcap, "cut.mcap", ["--pose-topic", "/odom"]),
    ] {
        let bytes = std::fs::read(&bag).unwrap();
        let cut = dir.path().join(name);
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let output = humem_eval(&[
            "--source",
            cut.to_str().unwrap(),
            options[0],
            options[1],
            "--keep-frames",
            &kept_arg,
            "--no-baseline",
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{name}: {stderr}");
        assert!(stderr.contains("damaged bag"), "{name}: {stderr}");
        assert!(stderr.contains(name), "{name}: {stderr}");
        assert!(!kept.exists(), "{name} left {}", kept.display());
    }

    // A topic that is not there: named, with the bag's topics listed.
    let output = humem_eval(&[
        "--source",
        recordings.join("ros2").to_str().unwrap(),
        "--image-topic",
        "/front/image",
        "--pose-topic",
        "/odom",
        "--keep-frames",
        &kept_arg,
    ]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(stderr.contains("no topic /front/image"), "{stderr}");
    assert!(
        stderr.contains("/camera/image_raw (sensor_msgs/Image, 105)"),
        "{stderr}"
    );
    assert!(!kept.exists());

    // Poses that never meet the images.
    let output = humem_eval(&[
        "--source",
        recordings.join("ros2").to_str().unwrap(),
        "--pose-topic",
        "/camera/image_raw",
    ]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("carries sensor_msgs/Image"), "{stderr}");

    // A bad line in a text layout: file and line named.
    let tum = recordings.join("tum");
    let truth = tum.join("groundtruth.txt");
    let text = std::fs::read_to_string(&truth).unwrap();
    let broken = text.replacen(" 1.5 ", " 1.5.0 ", 1);
    std::fs::write(&truth, broken).unwrap();
    let output = humem_eval(&["--source", tum.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(stderr.contains("groundtruth.txt, line 3"), "{stderr}");
}

#[test]
fn ingest_streams_a_bag_into_a_server_and_scores_its_candidates() {
    let dir = tempfile::tempdir().unwrap();
    let Some(recordings) = make_recordings(dir.path()) else {
        return;
    };
    let data = tempfile::tempdir().unwrap();
    let server = crate::harness::Server::start_with_models(data.path());
    let output = Command::new(env!("CARGO_BIN_EXE_humem"))
        .args(["ingest", "--source"])
        .arg(recordings.join("ros2"))
        .args([
            "--pose-topic",
            "/odom",
            "--keyframe-distance",
            "0",
            "--keyframe-angle",
            "0",
        ])
        .args([
            "--min-gap",
            MIN_GAP,
            "--robot",
            "car7",
            "--server",
            &server.url,
        ])
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    // One line per candidate, scored; then the summary.
    let true_places = stdout.lines().filter(|l| l.ends_with("true place")).count();
    assert!(true_places > 10, "{stdout}");
    let summary = stdout
        .lines()
        .find(|l| l.starts_with("| 105 |"))
        .unwrap_or_else(|| panic!("no summary row for 105 queries:\n{stdout}"));
    let cells: Vec<&str> = summary.split('|').map(str::trim).collect();
    let candidates: usize = cells[3].parse().unwrap();
    let lines = stdout
        .lines()
        .filter(|l| l.starts_with("keyframe "))
        .count();
    assert_eq!(candidates, lines, "{stdout}");
    assert!(
        cells[4].starts_with(&format!(
            "{:.3} ({true_places}/{candidates})",
            true_places as f64 / candidates as f64
        )),
        "{summary}"
    );
    assert!(
        stdout.contains("stored as robot \"car7\", session \"ros2\""),
        "{stdout}"
    );
    // The keyframes are on the server, with their poses.
    let stats = Command::new(env!("CARGO_BIN_EXE_humem"))
        .args(["stats", "--server", &server.url])
        .output()
        .unwrap();
    let stats = String::from_utf8_lossy(&stats.stdout);
    assert!(stats.contains("105"), "{stats}");
}
