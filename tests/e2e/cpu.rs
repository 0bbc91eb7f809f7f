//! Perception's CPU budget: with `perception.nice` set, every thread that
//! runs inference (the model workers and ONNX Runtime's intra-op pools)
//! runs at that nice value, and the rest of the server (the main thread,
//! tokio's workers that answer gRPC) keeps its own. Read from
//! `/proc/<pid>/task` of the real server.

use std::path::Path;

use crate::harness::{models_dir, Server};

/// `(tid, name, nice)` of every thread of process `pid`.
fn threads(pid: u32) -> Vec<(u32, String, i32)> {
    humem_perception::cpu::threads(pid)
        .unwrap()
        .into_iter()
        .map(|t| (t.tid, t.name, t.nice))
        .collect()
}

#[test]
fn perception_threads_run_at_the_configured_nice_and_the_service_does_not() {
    if !Path::new("/proc/self/task").is_dir() {
        eprintln!("skipped: no /proc (Linux only)");
        return;
    }
    if !models_dir().join("lib").is_dir() {
        eprintln!("skipped: models not installed (scripts/setup-models.sh)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with(
        dir.path(),
        &[
            "HUMEM_PERCEPTION__ENABLED=true",
            "HUMEM_PERCEPTION__NICE=11",
            "HUMEM_PERCEPTION__INTRA_THREADS=2",
        ],
    );
    let pid = server.pid();
    let roles = [
        "humem-descripto",
        "humem-ocr-det",
        "humem-ocr-rec",
        "humem-perceptio",
    ];
    // A new thread names itself once it runs: wait for every role's.
    let mut all = threads(pid);
    for _ in 0..50 {
        if roles
            .iter()
            .all(|role| all.iter().any(|(_, name, _)| name.starts_with(role)))
        {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
        all = threads(pid);
    }
    // Model workers are named after their role; ONNX Runtime's pool
    // threads keep the name of the thread that loaded the models.
    let perception = |name: &str| {
        [
            "humem-descripto",
            "humem-scene",
            "humem-ocr-",
            "humem-detector",
            "humem-perceptio",
        ]
        .iter()
        .any(|prefix| name.starts_with(prefix))
    };
    let (inference, rest): (Vec<_>, Vec<_>) = all.iter().partition(|(_, name, _)| perception(name));
    for role in [
        "humem-descripto",
        "humem-ocr-det",
        "humem-ocr-rec",
        "humem-perceptio",
    ] {
        assert!(
            inference.iter().any(|(_, name, _)| name.starts_with(role)),
            "a {role} thread: {all:?}"
        );
    }
    assert!(
        inference.iter().all(|&&(_, _, nice)| nice == 11),
        "every inference thread at nice 11: {all:?}"
    );
    // The main thread, tokio's workers (gRPC), the store's writers.
    assert!(rest.iter().any(|(_, name, _)| name.starts_with("tokio")));
    assert!(
        rest.iter().all(|&&(_, _, nice)| nice == 0),
        "the service keeps its priority: {all:?}"
    );
    server.kill();
}

#[test]
fn a_nice_value_that_would_raise_priority_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_humem"))
        .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(dir.path())
        .env("HUMEM_PERCEPTION__NICE", "-5")
        .env("HUMEM_PERCEPTION__ENABLED", "false")
        .env_remove("HUMEM_CONFIG")
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("perception.nice must be between 0 and 19"),
        "{stderr}"
    );
}
