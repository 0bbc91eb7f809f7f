//! Real `nats-server` processes for the cluster tests: a JetStream cluster
//! of N nodes on free loopback ports, each with its own store directory,
//! that a test can kill and start again. Tests skip, saying why, where
//! `nats-server` is not installed (`scripts/setup-system.sh test` installs
//! it).

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Whether `nats-server` can be run; prints why not.
pub fn available() -> bool {
    let found = Command::new("nats-server")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !found {
        eprintln!(
            "skipped: nats-server is not installed (scripts/setup-system.sh test installs it)"
        );
    }
    found
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// One node: its ports, its store and its process.
struct Node {
    name: String,
    client_port: u16,
    route_port: u16,
    /// HTTP monitoring (`/jsz`), to find the stream's leader.
    monitor_port: u16,
    store: PathBuf,
    child: Option<Child>,
}

/// A JetStream cluster on loopback.
pub struct NatsCluster {
    nodes: Vec<Node>,
    /// A configuration file every node reads (TLS, users), if any.
    config: Option<PathBuf>,
    _dir: tempfile::TempDir,
}

impl NatsCluster {
    /// Starts `n` nodes clustered with each other and waits until each
    /// accepts clients (JetStream elects its leader after; HuMem retries).
    pub fn start(n: usize) -> NatsCluster {
        Self::start_with(n, None)
    }

    /// Starts `n` nodes that also read `config` (nats-server's own format),
    /// e.g. a `tls` block and users; the ports and the store come from flags.
    pub fn start_with(n: usize, config: Option<&str>) -> NatsCluster {
        let dir = tempfile::tempdir().unwrap();
        let config = config.map(|text| {
            let path = dir.path().join("nats.conf");
            std::fs::write(&path, text).unwrap();
            path
        });
        let nodes = (0..n)
            .map(|i| Node {
                name: format!("n{i}"),
                client_port: free_port(),
                route_port: free_port(),
                monitor_port: free_port(),
                store: dir.path().join(format!("n{i}")),
                child: None,
            })
            .collect();
        let mut cluster = NatsCluster {
            nodes,
            config,
            _dir: dir,
        };
        for i in 0..n {
            cluster.start_node(i);
        }
        cluster
    }

    /// Starts node `i` (again), with its store as it was.
    pub fn start_node(&mut self, i: usize) {
        let routes: Vec<String> = self
            .nodes
            .iter()
            .map(|n| format!("nats://127.0.0.1:{}", n.route_port))
            .collect();
        let node = &mut self.nodes[i];
        let mut command = Command::new("nats-server");
        if let Some(config) = &self.config {
            command.arg("-c").arg(config);
        }
        command
            .args(["-a", "127.0.0.1", "-p"])
            .arg(node.client_port.to_string())
            .arg("-m")
            .arg(node.monitor_port.to_string())
            .args(["-n", &node.name, "-js", "-sd"])
            .arg(&node.store)
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        if routes.len() > 1 {
            command
                .args(["--cluster_name", "humem-test", "--cluster"])
                .arg(format!("nats://127.0.0.1:{}", node.route_port))
                .args(["--routes", &routes.join(",")]);
        }
        node.child = Some(command.spawn().expect("starting nats-server"));
        let deadline = Instant::now() + Duration::from_secs(10);
        while std::net::TcpStream::connect(("127.0.0.1", node.client_port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "nats-server {} did not start",
                node.name
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The node leading `stream`'s copies, as the nodes' monitoring
    /// endpoints report it (`/jsz`), if one does.
    pub fn stream_leader(&self, stream: &str) -> Option<usize> {
        use std::io::{Read, Write};
        for node in self.nodes.iter().filter(|n| n.child.is_some()) {
            let Ok(mut conn) = std::net::TcpStream::connect(("127.0.0.1", node.monitor_port))
            else {
                continue;
            };
            let _ = write!(
                conn,
                "GET /jsz?streams=true HTTP/1.0\r\nHost: localhost\r\n\r\n"
            );
            let mut response = String::new();
            if conn.read_to_string(&mut response).is_err() {
                continue;
            }
            let Some((_, body)) = response.split_once("\r\n\r\n") else {
                continue;
            };
            let Ok(jsz) = serde_json::from_str::<serde_json::Value>(body) else {
                continue;
            };
            let leader = jsz["account_details"]
                .as_array()
                .into_iter()
                .flatten()
                .flat_map(|a| a["stream_detail"].as_array().into_iter().flatten())
                .find(|s| s["name"] == stream)
                .and_then(|s| s["cluster"]["leader"].as_str().map(str::to_string));
            if let Some(leader) = leader {
                return self.nodes.iter().position(|n| n.name == leader);
            }
        }
        None
    }

    /// SIGKILL on node `i`.
    pub fn kill_node(&mut self, i: usize) {
        if let Some(mut child) = self.nodes[i].child.take() {
            child.kill().unwrap();
            child.wait().unwrap();
        }
    }

    /// Node `i`'s client port.
    pub fn client_port(&self, i: usize) -> u16 {
        self.nodes[i].client_port
    }

    /// The client URLs of every node, as `cluster.nats_urls` takes them
    /// from the environment.
    pub fn urls_setting(&self) -> String {
        self.urls_setting_as("nats", "127.0.0.1")
    }

    /// The same with another scheme and host name (`tls`, `localhost`).
    pub fn urls_setting_as(&self, scheme: &str, host: &str) -> String {
        let urls: Vec<String> = self
            .nodes
            .iter()
            .map(|n| format!("\"{scheme}://{host}:{}\"", n.client_port))
            .collect();
        format!("[{}]", urls.join(","))
    }
}

impl Drop for NatsCluster {
    fn drop(&mut self) {
        for i in 0..self.nodes.len() {
            self.kill_node(i);
        }
    }
}

/// Publishes one message with one header on `subject` through node
/// `port`, speaking NATS's text protocol (CONNECT, HPUB, then PING until
/// PONG, so the server has taken it): an entry no HuMem build would
/// write, for the tests of what a replica does with one.
pub fn publish_raw(port: u16, subject: &str, header: (&str, &str), payload: &[u8]) {
    use std::io::{BufRead, BufReader, Write};
    let stream = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut line = String::new();
    reader.read_line(&mut line).unwrap();
    assert!(line.starts_with("INFO"), "{line}");
    let headers = format!("NATS/1.0\r\n{}: {}\r\n\r\n", header.0, header.1);
    let mut out = Vec::new();
    out.extend_from_slice(b"CONNECT {\"verbose\":false,\"headers\":true,\"protocol\":1}\r\n");
    out.extend_from_slice(
        format!(
            "HPUB {subject} {} {}\r\n{headers}",
            headers.len(),
            headers.len() + payload.len()
        )
        .as_bytes(),
    );
    out.extend_from_slice(payload);
    out.extend_from_slice(b"\r\nPING\r\n");
    (&stream).write_all(&out).unwrap();
    loop {
        line.clear();
        assert!(
            reader.read_line(&mut line).unwrap() > 0,
            "NATS closed the connection"
        );
        assert!(!line.starts_with("-ERR"), "{line}");
        if line.starts_with("PONG") {
            return;
        }
    }
}
