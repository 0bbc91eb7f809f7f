//! The command-line client against the real server: JSON in, JSON out.

use std::io::Write;
use std::process::{Command, Stdio};

use humem_server::proto;

use crate::harness::Server;
use crate::scenes::{self, World};

fn humem(server: &Server, args: &[&str], stdin: &str) -> (bool, String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_humem"))
        .args(args)
        .args(["--server", &server.url])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running humem");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(stdin.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    (
        out.status.success(),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

#[tokio::test(flavor = "multi_thread")]
async fn insert_query_and_maintain_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path());
    let mut world = World::new(60, 8);
    let drive = scenes::loop_drive(&mut world, "cli-robot", "s", 0, 60, 10);
    // Keyframes as proto3 JSON lines, the way a script would write them.
    let lines: Vec<String> = drive
        .iter()
        .map(|(kf, _)| serde_json::to_string(kf).unwrap())
        .collect();
    let (ok, out, err) = humem(&server, &["insert", "--batch", "16"], &lines.join("\n"));
    assert!(ok, "{err}");
    assert_eq!(
        out.trim(),
        "inserted 70 keyframes (0 replaced); the store holds 70"
    );

    // Revisit of place 3 is keyframe 63.
    let query = serde_json::to_string(&scenes::query_stored("cli-robot", "s", 63)).unwrap();
    let (ok, out, err) = humem(&server, &["query", "--output", "json"], &query);
    assert!(ok, "{err}");
    let reply: proto::QueryResponse = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(reply.candidates[0].keyframe_id, 3);

    let (ok, out, _) = humem(&server, &["query", "--output", "table"], &query);
    assert!(ok);
    assert!(out.contains("cli-robot keyframe 63:"), "{out}");

    let (ok, out, err) = humem(
        &server,
        &["erase", "--robot", "cli-robot", "--session", "s", "3", "4"],
        "",
    );
    assert!(ok, "{err}");
    assert_eq!(out.trim(), "erased 2");
    let (ok, out, _) = humem(&server, &["stats"], "");
    assert!(ok);
    let stats: proto::StatsResponse = serde_json::from_str(&out).unwrap();
    assert_eq!(stats.keyframes, 68);

    // Bad input is reported with the field, and the exit status says so.
    let bad = lines[0].replace("\"robotId\":\"cli-robot\"", "\"robotId\":\"\"");
    let (ok, _, err) = humem(&server, &["insert"], &bad);
    assert!(!ok);
    assert!(
        err.contains("InvalidArgument") && err.contains("keyframes[0].robot_id: required"),
        "{err}"
    );
    let (ok, _, err) = humem(&server, &["insert"], "{not json");
    assert!(!ok);
    assert!(err.contains("not valid JSON"), "{err}");
}
