//! A full disk: the store on a small tmpfs (mounted by the test; it needs
//! root and is skipped, saying so, without). Inserts past the space get a
//! clean error, never INTERNAL or a crash, and every acknowledged keyframe
//! is there after the server is restarted on a larger disk.

use std::path::Path;
use std::process::Command;

use humem_server::proto;
use tonic::Code;

use crate::harness::Server;
use crate::scenes::{self, World};

/// A tmpfs of `megabytes` at `dir`, unmounted when dropped.
struct Tmpfs<'a>(&'a Path);

impl<'a> Tmpfs<'a> {
    fn mount(dir: &'a Path, megabytes: u32) -> Option<Tmpfs<'a>> {
        let status = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={megabytes}m"), "tmpfs"])
            .arg(dir)
            .stderr(std::process::Stdio::null())
            .status()
            .ok()?;
        status.success().then_some(Tmpfs(dir))
    }

    fn resize(&self, megabytes: u32) {
        let status = Command::new("mount")
            .args(["-o", &format!("remount,size={megabytes}m")])
            .arg(self.0)
            .status()
            .unwrap();
        assert!(status.success());
    }
}

impl Drop for Tmpfs<'_> {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(self.0).status();
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn a_full_disk_gives_a_clean_error_and_loses_nothing_acknowledged() {
    let dir = tempfile::tempdir().unwrap();
    let Some(disk) = Tmpfs::mount(dir.path(), 24) else {
        eprintln!(
            "skipped: mounting a tmpfs needs root (run the tests as root to check a full disk)"
        );
        return;
    };
    let data = dir.path().join("data");
    // 8 MB kept free: the inserts stop cleanly at about 16 MB.
    const RESERVE: &str = "HUMEM_STORE__MIN_FREE_BYTES=8388608";
    let server = Server::start_with(&data, &[RESERVE]);
    let mut client = server.client().await;
    let mut world = World::new(4000, 9);
    let mut acknowledged = Vec::new();
    let mut refusals = Vec::new();
    let mut k = 0u64;
    // Keyframes of 16 KB of descriptor each until the disk refuses.
    while refusals.len() < 5 && k < 4000 {
        let mut kf = scenes::keyframe(
            "r",
            "s",
            [k, 3 * k, 0],
            scenes::features(world.view(k as usize, 0.3), 1, vec![]),
        );
        if let Some(proto::keyframe::Content::Features(f)) = kf.content.as_mut() {
            f.global_descriptor = f
                .global_descriptor
                .iter()
                .cycle()
                .take(4096)
                .copied()
                .collect();
        }
        match client
            .insert(proto::InsertRequest { keyframe: Some(kf) })
            .await
        {
            Ok(_) => acknowledged.push(k),
            Err(status) => refusals.push(status),
        }
        k += 1;
    }
    assert!(
        !refusals.is_empty(),
        "24 MB held {} keyframes of 16 KB",
        acknowledged.len()
    );
    for status in &refusals {
        assert_eq!(status.code(), Code::ResourceExhausted, "{status:?}");
        assert!(status.message().contains("nearly full"), "{status:?}");
        assert!(status.metadata().get("retry-after-ms").is_some());
    }
    eprintln!(
        "full disk: {} keyframes acknowledged, then refused: {}",
        acknowledged.len(),
        refusals[0].message()
    );
    // The server still answers, and erasing (which makes room) still works.
    client.stats(proto::StatsRequest {}).await.unwrap();
    let last = acknowledged.pop().unwrap();
    let erased = client
        .erase(proto::EraseRequest {
            robot_id: "r".into(),
            session_id: "s".into(),
            keyframe_ids: vec![last],
        })
        .await
        .unwrap()
        .into_inner()
        .erased;
    assert_eq!(erased, 1);
    server.kill();

    disk.resize(64);
    let server = Server::start_with(&data, &[RESERVE]);
    let mut client = server.client().await;
    let stats = client
        .stats(proto::StatsRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(stats.keyframes >= acknowledged.len() as u64);
    for k in &acknowledged {
        let reply = client
            .erase(proto::EraseRequest {
                robot_id: "r".into(),
                session_id: "s".into(),
                keyframe_ids: vec![*k],
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(reply.erased, 1, "acknowledged keyframe {k} was lost");
    }
}
