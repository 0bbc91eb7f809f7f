//! Connecting to a HuMem server as a client: the one place that knows the
//! channel settings every client of this workspace uses (the command line,
//! `humem load`, `humem eval --server`), so they cannot drift apart.

use anyhow::Context;
use tonic::transport::Channel;

use crate::proto::place_recognition_client::PlaceRecognitionClient;

/// Largest message a client sends or accepts (the server's default limit).
const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// Connects to the server at `url` (`http://HOST:PORT`).
pub async fn connect(url: &str) -> anyhow::Result<PlaceRecognitionClient<Channel>> {
    let channel = Channel::from_shared(url.to_string())
        .with_context(|| format!("invalid server URL {url:?}"))?
        .connect()
        .await
        .with_context(|| format!("connecting to {url}"))?;
    Ok(PlaceRecognitionClient::new(channel)
        .max_decoding_message_size(MAX_MESSAGE_BYTES)
        .max_encoding_message_size(MAX_MESSAGE_BYTES))
}
