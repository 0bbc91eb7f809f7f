//! `humem eval --source` on one drive written in every recording format:
//! a ROS 2 MCAP bag, a ROS 1 bag, TUM RGB-D, EuRoC and KITTI, made at test
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
    let sources: [(&str, &[&str]); 5] = [
        ("ros2", &["--pose-topic", "/odom"]),
        ("drive.bag", &["--tf-frames", "map,camera"]),
        ("tum", &[]),
        ("euroc", &[]),
        ("kitti", &[]),
    ];
    for (name, options) in sources {
        let source = path(name);
        let mut extra: Vec<&str> = every_image.to_vec();
        extra.extend(options);
        let figures = eval_figures(&["--source", &source], &extra, dir.path());
        assert_eq!(figures, folder, "{name} differs from the folder form");
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
