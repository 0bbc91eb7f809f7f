//! The client commands: JSON in, gRPC calls, JSON or a table out.
//!
//! One function per command, taking the command's flags; the parent module
//! matches the command line to them, so this module needs only the shared
//! flag groups ([`super::args`]), never the command enum above it.

use std::io::{IsTerminal, Read};
use std::path::Path;

use anyhow::{bail, Context};
use serde::de::DeserializeOwned;

use super::args::{Output, ServerArg, SessionArgs};
use humem_server::client::connect;
use humem_server::proto;

fn read_input(file: &Path) -> anyhow::Result<String> {
    let mut text = String::new();
    if file == Path::new("-") {
        std::io::stdin()
            .read_to_string(&mut text)
            .context("reading standard input")?;
    } else {
        text =
            std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    }
    Ok(text)
}

/// Messages from JSON text: one array of them, or a sequence of objects
/// (one per line, or just concatenated).
pub fn parse_messages<T: DeserializeOwned>(text: &str, what: &str) -> anyhow::Result<Vec<T>> {
    let mut out = Vec::new();
    for (n, value) in serde_json::Deserializer::from_str(text)
        .into_iter::<serde_json::Value>()
        .enumerate()
    {
        let value = value.with_context(|| format!("JSON value {} is not valid JSON", n + 1))?;
        let items = match value {
            serde_json::Value::Array(items) => items,
            other => vec![other],
        };
        for item in items {
            let index = out.len();
            out.push(
                serde_json::from_value(item)
                    .with_context(|| format!("{what} {index} does not match the API"))?,
            );
        }
    }
    Ok(out)
}

fn status_error(call: &str, status: tonic::Status) -> anyhow::Error {
    anyhow::anyhow!("{call} failed: {:?}: {}", status.code(), status.message())
}

/// `humem insert`: stores the keyframes of `file`, `batch` a call.
pub async fn insert(server: &ServerArg, file: &Path, batch: usize) -> anyhow::Result<()> {
    let keyframes: Vec<proto::Keyframe> = parse_messages(&read_input(file)?, "keyframe")?;
    if keyframes.is_empty() {
        bail!("no keyframes in {}", file.display());
    }
    let mut client = connect(&server.server, &server.tls).await?;
    let mut replaced = 0;
    let mut stored = 0;
    for chunk in keyframes.chunks(batch.max(1)) {
        let reply = client
            .insert_batch(proto::InsertBatchRequest {
                keyframes: chunk.to_vec(),
            })
            .await
            .map_err(|s| status_error("InsertBatch", s))?
            .into_inner();
        replaced += reply.replaced;
        stored = reply.store_keyframes;
    }
    println!(
        "inserted {} keyframes ({replaced} replaced); the store holds {stored}",
        keyframes.len()
    );
    Ok(())
}

/// `humem query`: runs the queries of `file`, printing each answer as
/// `output` says (default: a table on a terminal, JSON otherwise).
pub async fn query(server: &ServerArg, file: &Path, output: Option<Output>) -> anyhow::Result<()> {
    let queries: Vec<proto::QueryRequest> = parse_messages(&read_input(file)?, "query")?;
    let output = output.unwrap_or(if std::io::stdout().is_terminal() {
        Output::Table
    } else {
        Output::Json
    });
    let mut client = connect(&server.server, &server.tls).await?;
    for query in queries {
        let reply = client
            .query(query.clone())
            .await
            .map_err(|s| status_error("Query", s))?
            .into_inner();
        match output {
            Output::Json => println!("{}", serde_json::to_string(&reply)?),
            Output::Table => print_table(&query, &reply),
        }
    }
    Ok(())
}

/// `humem erase`: removes keyframes of a session.
pub async fn erase(
    server: &ServerArg,
    session: SessionArgs,
    keyframe_ids: Vec<u64>,
) -> anyhow::Result<()> {
    let reply = connect(&server.server, &server.tls)
        .await?
        .erase(proto::EraseRequest {
            robot_id: session.robot,
            session_id: session.session,
            keyframe_ids,
        })
        .await
        .map_err(|s| status_error("Erase", s))?;
    println!("erased {}", reply.get_ref().erased);
    Ok(())
}

/// `humem reset-map`: removes every keyframe of a map.
pub async fn reset_map(server: &ServerArg, session: SessionArgs, map: u64) -> anyhow::Result<()> {
    let reply = connect(&server.server, &server.tls)
        .await?
        .reset_map(proto::ResetMapRequest {
            robot_id: session.robot,
            session_id: session.session,
            map_id: Some(map),
        })
        .await
        .map_err(|s| status_error("ResetMap", s))?;
    println!("erased {}", reply.get_ref().erased);
    Ok(())
}

/// `humem reset-session`: removes every keyframe of a session.
pub async fn reset_session(server: &ServerArg, session: SessionArgs) -> anyhow::Result<()> {
    let reply = connect(&server.server, &server.tls)
        .await?
        .reset_session(proto::ResetSessionRequest {
            robot_id: session.robot,
            session_id: session.session,
        })
        .await
        .map_err(|s| status_error("ResetSession", s))?;
    println!("erased {}", reply.get_ref().erased);
    Ok(())
}

/// `humem stats`: prints what the store holds.
pub async fn stats(server: &ServerArg) -> anyhow::Result<()> {
    let reply = connect(&server.server, &server.tls)
        .await?
        .stats(proto::StatsRequest {})
        .await
        .map_err(|s| status_error("Stats", s))?;
    println!("{}", serde_json::to_string_pretty(reply.get_ref())?);
    Ok(())
}

fn print_table(query: &proto::QueryRequest, reply: &proto::QueryResponse) {
    let what = match (query.keyframe_id, query.frame_id) {
        (Some(kf), _) => format!("keyframe {kf}"),
        (None, Some(f)) => format!("frame {f}"),
        (None, None) => "query".into(),
    };
    println!(
        "{} {what}: {} candidates of {} eligible keyframes",
        query.robot_id,
        reply.candidates.len(),
        reply.eligible_keyframes
    );
    if reply.candidates.is_empty() {
        return;
    }
    println!(
        "{:>4}  {:<12} {:<10} {:>10} {:>6} {:>8}  {:>6} {:>6} {:>6} {:>6}",
        "rank", "robot", "session", "keyframe", "map", "frame", "score", "S_s", "S_o", "S_t"
    );
    for (rank, c) in reply.candidates.iter().enumerate() {
        let e = c.evidence.clone().unwrap_or_default();
        println!(
            "{:>4}  {:<12} {:<10} {:>10} {:>6} {:>8}  {:>6.3} {:>6.3} {:>6.3} {:>6.3}",
            rank + 1,
            c.robot_id,
            c.session_id,
            c.keyframe_id,
            c.map_id,
            c.frame_id,
            c.score,
            e.scene_score,
            e.object_score,
            e.text_score
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_arrays_and_object_streams_in_proto_json() {
        let text = r#"{"robotId": "r", "keyframeId": "3", "frameId": 30, "mapId": 0}
        [{"robotId": "r", "keyframeId": 4}, {"robotId": "q"}]"#;
        let kfs: Vec<proto::Keyframe> = parse_messages(text, "keyframe").unwrap();
        assert_eq!(kfs.len(), 3);
        assert_eq!(kfs[0].keyframe_id, Some(3));
        assert_eq!(kfs[0].frame_id, Some(30));
        assert_eq!(kfs[1].keyframe_id, Some(4));
        assert_eq!(kfs[2].robot_id, "q");
        let err = parse_messages::<proto::Keyframe>(r#"{"robotId": 5}"#, "keyframe").unwrap_err();
        assert!(err.to_string().contains("keyframe 0"), "{err}");
    }
}
