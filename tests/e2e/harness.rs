//! Starting, stopping and killing the real server binary.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use humem_server::proto::place_recognition_client::PlaceRecognitionClient;
use tonic::transport::Channel;

/// The repository's root (the e2e tests belong to `crates/humem`).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Runs `command` to completion and returns its standard output; fails the
/// test, showing both outputs, if it does not succeed.
pub fn output_of(command: &mut Command) -> String {
    let output = command
        .output()
        .unwrap_or_else(|e| panic!("running {command:?}: {e}"));
    let stdout = String::from_utf8_lossy(&output.stdout).to_string();
    assert!(
        output.status.success(),
        "{command:?} failed ({}):\n{stdout}{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

/// The repository's models folder, filled by `scripts/setup-models.sh`.
pub fn models_dir() -> PathBuf {
    repo_root().join("models")
}

/// The shared data sets, if this checkout has `../shared` beside it.
pub fn datasets() -> Option<PathBuf> {
    let dir = repo_root().join("../shared/datasets");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!(
            "skipped: {} is absent (the shared data sets are not beside this checkout)",
            dir.display()
        );
        None
    }
}

/// A running `humem serve`.
pub struct Server {
    child: Option<Child>,
    pub url: String,
    /// Address of the Prometheus endpoint.
    pub metrics: String,
    pub data_dir: PathBuf,
    /// The extra arguments and settings it was started with.
    extra: Vec<String>,
}

impl Server {
    /// Starts the server on a free port with `data_dir` as its store.
    pub fn start(data_dir: &Path) -> Server {
        Self::start_with(data_dir, &[])
    }

    /// Starts the server with the perception models installed by
    /// `scripts/setup-models.sh`.
    pub fn start_with_models(data_dir: &Path) -> Server {
        Self::start_with(data_dir, &["HUMEM_PERCEPTION__ENABLED=true"])
    }

    /// Starts the server with extra `serve` arguments or `KEY=VALUE`
    /// environment settings (those containing `=`). Perception is off unless
    /// asked for: most tests send precomputed features and start faster.
    pub fn start_with(data_dir: &Path, extra: &[&str]) -> Server {
        let mut command = Command::new(env!("CARGO_BIN_EXE_humem"));
        command
            .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(data_dir)
            .env("RUST_LOG", "warn,ort::logging=error")
            .env("HUMEM_PERCEPTION__ENABLED", "false")
            .env("HUMEM_METRICS__LISTEN", "127.0.0.1:0")
            .env("HUMEM_PERCEPTION__MODELS_DIR", models_dir())
            .env_remove("HUMEM_CONFIG")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        for arg in extra {
            match arg.split_once('=') {
                Some((key, value)) if !arg.starts_with("--") => {
                    command.env(key, value);
                }
                _ => {
                    command.arg(arg);
                }
            }
        }
        let mut child = command.spawn().expect("starting humem serve");
        let stdout = child.stdout.take().expect("piped stdout");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut metrics = String::new();
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if let Some(addr) = line.strip_prefix("humem metrics on ") {
                    metrics = addr.to_string();
                }
                if let Some(addr) = line.strip_prefix("humem listening on ") {
                    let _ = tx.send((addr.to_string(), metrics.clone()));
                }
            }
        });
        let (addr, metrics) = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("humem serve did not report its address");
        Server {
            child: Some(child),
            url: format!("http://{addr}"),
            metrics,
            data_dir: data_dir.to_path_buf(),
            extra: extra.iter().map(|a| a.to_string()).collect(),
        }
    }

    /// The server process's id.
    pub fn pid(&self) -> u32 {
        self.child.as_ref().expect("server running").id()
    }

    pub async fn client(&self) -> PlaceRecognitionClient<Channel> {
        PlaceRecognitionClient::connect(self.url.clone())
            .await
            .expect("connecting to humem")
            .max_encoding_message_size(64 << 20)
    }

    pub async fn channel(&self) -> Channel {
        Channel::from_shared(self.url.clone())
            .unwrap()
            .connect()
            .await
            .expect("connecting to humem")
    }

    /// What the store holds (the Stats RPC). A call that fails while the
    /// server still runs is tried once more on a new connection (the
    /// failure is printed); one that fails because the server is gone
    /// fails the test, saying so.
    pub async fn stats(&self) -> humem_server::proto::StatsResponse {
        let mut tries = 0;
        loop {
            let call = self
                .client()
                .await
                .stats(humem_server::proto::StatsRequest {})
                .await;
            match call {
                Ok(reply) => return reply.into_inner(),
                Err(status) => {
                    tries += 1;
                    let state = self.process_state();
                    assert!(
                        tries < 2 && (state.starts_with('R') || state.starts_with('S')),
                        "Stats failed ({status:?}); the server process: {state}"
                    );
                    eprintln!("Stats failed ({status:?}) with the server running; trying again");
                }
            }
        }
    }

    /// The server process's state as /proc shows it (`S (sleeping)`,
    /// `Z (zombie)` for one that exited), or why it cannot be read.
    fn process_state(&self) -> String {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.pid()));
        match status {
            Ok(text) => text
                .lines()
                .find_map(|l| l.strip_prefix("State:"))
                .unwrap_or("unknown")
                .trim()
                .to_string(),
            Err(e) => format!("unreadable: {e}"),
        }
    }

    /// The Prometheus exposition, fetched over plain HTTP/1.1.
    pub fn scrape(&self) -> String {
        use std::io::{Read, Write};
        let mut stream = std::net::TcpStream::connect(&self.metrics).expect("metrics endpoint");
        write!(
            stream,
            "GET /metrics HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            self.metrics
        )
        .unwrap();
        let mut response = String::new();
        stream.read_to_string(&mut response).unwrap();
        assert!(response.starts_with("HTTP/1.1 200"), "{response}");
        response
    }

    /// The value of one sample of the exposition (`name{labels}` exactly as
    /// printed, labels sorted), if present.
    pub fn sample(exposition: &str, series: &str) -> Option<f64> {
        exposition.lines().find_map(|line| {
            let (name, value) = line.rsplit_once(' ')?;
            (name == series).then(|| value.parse().unwrap())
        })
    }

    /// SIGKILL: no chance to flush anything.
    pub fn kill(mut self) {
        let mut child = self.child.take().unwrap();
        child.kill().expect("SIGKILL");
        child.wait().unwrap();
    }

    /// SIGTERM, then waits; returns the exit status.
    pub fn terminate(mut self) -> std::process::ExitStatus {
        let mut child = self.child.take().unwrap();
        let status = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .expect("running kill");
        assert!(status.success());
        for _ in 0..600 {
            if let Some(status) = child.try_wait().unwrap() {
                return status;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        child.kill().ok();
        panic!("humem did not stop within 30 s of SIGTERM");
    }

    /// Stops this server and starts another on the same data directory,
    /// with the same arguments and settings.
    pub fn restart(self) -> Server {
        let dir = self.data_dir.clone();
        let extra = self.extra.clone();
        let status = self.terminate();
        assert!(status.success(), "humem exited with {status}");
        let extra: Vec<&str> = extra.iter().map(String::as_str).collect();
        Server::start_with(&dir, &extra)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}
