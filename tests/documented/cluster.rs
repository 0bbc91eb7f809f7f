//! The two-replica cluster as documented: the cluster of
//! docs/fleet-and-cluster.md ("Start it") is taken from the page itself and
//! run by `bash` from the repository root — three real `nats-server`
//! processes and two replicas — with two changes only: the replicas are the
//! binary under test (`scripts/run.sh` builds and runs the same `humem
//! serve` with a release build first), and `/tmp/` is a temporary folder.
//! A keyframe written to one replica must be answered by the other.

use std::os::unix::process::CommandExt;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::harness::{output_of, repo_root};

/// The first `sh` block after `marker` in `page`.
fn block_after(page: &str, marker: &str) -> String {
    let text = std::fs::read_to_string(repo_root().join(page)).unwrap();
    let after = &text[text
        .find(marker)
        .unwrap_or_else(|| panic!("{page}: no {marker:?}"))..];
    let start = after.find("```sh\n").expect("a sh block") + "```sh\n".len();
    let end = after[start..].find("```").expect("the block's end");
    after[start..start + end].to_string()
}

/// Kills a process group when dropped, so a failed test leaves nothing.
struct Group(u32);

impl Drop for Group {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", "--", &format!("-{}", self.0)])
            .status();
        std::thread::sleep(Duration::from_millis(500));
        let _ = Command::new("kill")
            .args(["-KILL", "--", &format!("-{}", self.0)])
            .status();
    }
}

fn humem(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_humem"));
    command.args(args).env_remove("HUMEM_CONFIG");
    command
}

#[test]
fn the_documented_two_replica_cluster_starts_and_replicates() {
    if !crate::nats::available() {
        return;
    }
    let block = block_after("docs/fleet-and-cluster.md", "**Start it**");
    assert!(block.contains("scripts/run.sh"), "{block}");
    // The page's fixed ports must be free, or the failure would be another
    // program's; one held for a moment by an outgoing connection is waited
    // for.
    let deadline = Instant::now() + Duration::from_secs(60);
    for port in [4220, 4221, 4222, 6220, 6221, 6222, 9461, 9462, 50051, 50052] {
        while std::net::TcpListener::bind(("127.0.0.1", port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "port {port}, which docs/fleet-and-cluster.md uses, is taken on this machine"
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }
    let tmp = tempfile::tempdir().unwrap();
    // `/tmp/` first: the binary's own path may lie under /tmp.
    let script = block
        .replace("/tmp/", &format!("{}/", tmp.path().display()))
        .replace(
            "scripts/run.sh",
            &format!("{} serve", env!("CARGO_BIN_EXE_humem")),
        );
    // What the servers print, shown when the test fails.
    let log = tmp.path().join("servers.log");
    let tail = || {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        // The servers' own lines, not the NATS servers' chatter.
        let ours: Vec<&str> = lines
            .iter()
            .copied()
            .filter(|l| !l.contains("] [INF] "))
            .collect();
        ours[ours.len().saturating_sub(60)..].join("\n")
    };
    let output = std::fs::File::create(&log).unwrap();
    let mut child = Command::new("bash")
        .arg("-c")
        .arg(format!("{script}\nwait"))
        .current_dir(repo_root())
        .env_remove("HUMEM_CONFIG")
        .env(
            "RUST_LOG",
            "warn,humem_server=info,humem_cluster=info,ort::logging=error",
        )
        .env("RUST_BACKTRACE", "0")
        .env("RUST_LIB_BACKTRACE", "0")
        .stdout(output.try_clone().unwrap())
        .stderr(output)
        .process_group(0)
        .spawn()
        .unwrap();
    let _group = Group(child.id());

    // Both replicas ready (each has applied the stream as it found it);
    // the replicas load the default models first, slowly on a machine busy
    // with other tests.
    let deadline = Instant::now() + Duration::from_secs(300);
    for port in [9461, 9462] {
        let url = format!("http://127.0.0.1:{port}/readyz");
        loop {
            if let Ok(Some(status)) = child.try_wait() {
                panic!(
                    "the documented commands exited with {status} before replica {port} was ready:\n{}",
                    tail()
                );
            }
            let ready = humem(&["probe", "--url", &url])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success());
            if ready {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "{url} never answered ready:\n{}",
                tail()
            );
            std::thread::sleep(Duration::from_millis(300));
        }
    }

    // A keyframe written to the first replica is answered by the second.
    let keyframe = r#"{"robotId":"r1","sessionId":"s","keyframeId":1,"frameId":10,"mapId":0,"pose":{"translation":{"x":0,"y":0,"z":0},"rotation":{"w":1}},"features":{"globalDescriptor":[0.6,0.8]}}"#;
    let mut insert = humem(&["insert", "--server", "http://127.0.0.1:50051"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    insert
        .stdin
        .take()
        .unwrap()
        .write_all(keyframe.as_bytes())
        .unwrap();
    let inserted = insert.wait_with_output().unwrap();
    assert!(
        inserted.status.success(),
        "{}",
        String::from_utf8_lossy(&inserted.stderr)
    );
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let stats = output_of(&mut humem(&["stats", "--server", "http://127.0.0.1:50052"]));
        if stats.contains("\"keyframes\": \"1\"") || stats.contains("\"keyframes\": 1") {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the second replica never held the keyframe:\n{stats}\n{}",
            tail()
        );
        std::thread::sleep(Duration::from_millis(300));
    }
}
