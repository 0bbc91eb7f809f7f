//! `humem export`: the keyframes a stopped server's store holds, one JSON
//! object per line (proto3 JSON of `Keyframe`, without its features).
//!
//! It opens the sled store directly, so it runs only while no server holds
//! the data directory (sled admits one process). It exists so that a client
//! can check what the store holds against its own map, e.g. the ORB-SLAM3
//! harness comparing map ids and poses after merges and loop corrections,
//! without an RPC that would stream the whole store from a live server.

use std::io::Write;
use std::path::Path;

use anyhow::Context;

use humem_server::api::convert;
use humem_server::proto;
use humem_store::Store;

/// Prints every stored keyframe (ordered by robot, session, keyframe id) and
/// returns how many were printed.
pub fn export(data_dir: &Path, out: &mut dyn Write) -> anyhow::Result<usize> {
    let store = Store::open(data_dir, 0, 1).with_context(|| {
        format!(
            "opening the store in {} (is a server running on it?)",
            data_dir.display()
        )
    })?;
    let index = store.index();
    let mut rows: Vec<usize> = (0..index.len()).collect();
    rows.sort_by(|&a, &b| index.meta(a).key.cmp(&index.meta(b).key));
    for &row in &rows {
        let meta = index.meta(row);
        let keyframe = proto::Keyframe {
            robot_id: meta.key.robot_id.clone(),
            session_id: meta.key.session_id.clone(),
            keyframe_id: Some(meta.key.keyframe_id),
            frame_id: Some(meta.frame_id),
            map_id: Some(meta.map_id),
            timestamp: meta.timestamp,
            pose: Some(convert::pose(&meta.pose)),
            ..Default::default()
        };
        writeln!(out, "{}", serde_json::to_string(&keyframe)?)?;
    }
    Ok(rows.len())
}
