//! TLS on the gRPC port, with certificates made in the test (rcgen): a
//! client that trusts the server's CA is served; one that trusts another
//! CA, or speaks plaintext, fails cleanly and the server goes on; mutual TLS
//! refuses clients without a certificate from its client CA; and a new
//! certificate written over the old files is served without a restart.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::harness::Server;
use crate::pki::Authority;
use humem_server::client::ClientCredentials;
use humem_server::proto;

pub fn trusting(ca: &Path) -> ClientCredentials {
    ClientCredentials {
        tls_ca: Some(ca.to_path_buf()),
        ..ClientCredentials::default()
    }
}

pub fn https(server: &Server) -> String {
    server.url.replace("http://", "https://")
}

/// Stats over a fresh connection, with a deadline: Ok(keyframes) or the
/// whole error chain as text.
pub async fn stats(url: &str, tls: &ClientCredentials) -> Result<u64, String> {
    let call = async {
        let mut client = humem_server::client::connect(url, tls).await?;
        let reply = client.stats(proto::StatsRequest {}).await?;
        anyhow::Ok(reply.into_inner().keyframes)
    };
    match tokio::time::timeout(Duration::from_secs(10), call).await {
        Ok(result) => result.map_err(|e| format!("{e:#}")),
        Err(_) => Err("timed out".into()),
    }
}

pub fn tls_env(cert: &Path, key: &Path) -> Vec<String> {
    vec![
        format!("HUMEM_SERVER__TLS__CERT={}", cert.display()),
        format!("HUMEM_SERVER__TLS__KEY={}", key.display()),
    ]
}

fn start(dir: &Path, env: &[String]) -> Server {
    let env: Vec<&str> = env.iter().map(String::as_str).collect();
    Server::start_with(&dir.join("data"), &env)
}

#[tokio::test(flavor = "multi_thread")]
async fn tls_serves_clients_that_trust_its_ca_and_refuses_the_rest_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let ca = Authority::new("HuMem test CA");
    let ca_file = ca.write_ca(dir.path(), "ca");
    let (cert, key) = ca.issue(dir.path(), "server", &["localhost", "127.0.0.1"]);
    let server = start(dir.path(), &tls_env(&cert, &key));
    let url = https(&server);

    // Trusting the CA: served, by IP address and by name.
    assert_eq!(stats(&url, &trusting(&ca_file)).await, Ok(0));
    let by_name = url.replace("127.0.0.1", "localhost");
    assert_eq!(stats(&by_name, &trusting(&ca_file)).await, Ok(0));

    // Trusting another CA: the handshake fails on the certificate.
    let other = Authority::new("Another CA").write_ca(dir.path(), "other-ca");
    let err = stats(&url, &trusting(&other)).await.unwrap_err();
    assert!(err.contains("certificate"), "{err}");

    // A name the certificate does not hold.
    let wrong_name = ClientCredentials {
        tls_server_name: Some("humem.example".into()),
        ..trusting(&ca_file)
    };
    let err = stats(&url, &wrong_name).await.unwrap_err();
    assert!(err.contains("certificate"), "{err}");

    // Plaintext to the TLS port fails, promptly, with an error.
    let err = stats(&server.url, &ClientCredentials::default())
        .await
        .unwrap_err();
    assert_ne!(err, "timed out");

    // And the server goes on serving, with each failure counted.
    assert_eq!(stats(&url, &trusting(&ca_file)).await, Ok(0));
    let failures = Server::sample(&server.scrape(), "humem_tls_handshake_failures_total");
    assert!(failures >= Some(3.0), "{failures:?}");

    // Options that do not fit the URL are refused before connecting.
    let err = stats(&server.url, &trusting(&ca_file)).await.unwrap_err();
    assert!(err.contains("not an https:// URL"), "{err}");
}

#[tokio::test(flavor = "multi_thread")]
async fn mutual_tls_serves_only_clients_with_a_certificate_from_its_client_ca() {
    let dir = tempfile::tempdir().unwrap();
    let ca = Authority::new("HuMem test CA");
    let ca_file = ca.write_ca(dir.path(), "ca");
    let (cert, key) = ca.issue(dir.path(), "server", &["localhost", "127.0.0.1"]);
    let robots = Authority::new("Fleet robots CA");
    let robots_file = robots.write_ca(dir.path(), "robots-ca");
    let (robot_cert, robot_key) = robots.issue(dir.path(), "robot-1", &["robot-1"]);
    let (stranger_cert, stranger_key) = ca.issue(dir.path(), "stranger", &["stranger"]);

    let mut env = tls_env(&cert, &key);
    env.push(format!(
        "HUMEM_SERVER__TLS__CLIENT_CA={}",
        robots_file.display()
    ));
    let server = start(dir.path(), &env);
    let url = https(&server);
    let with_identity = |cert: &Path, key: &Path| ClientCredentials {
        tls_cert: Some(cert.to_path_buf()),
        tls_key: Some(key.to_path_buf()),
        ..trusting(&ca_file)
    };

    assert_eq!(
        stats(&url, &with_identity(&robot_cert, &robot_key)).await,
        Ok(0)
    );
    // No certificate, or one from a CA the server does not take for clients.
    let err = stats(&url, &trusting(&ca_file)).await.unwrap_err();
    assert_ne!(err, "timed out");
    let err = stats(&url, &with_identity(&stranger_cert, &stranger_key))
        .await
        .unwrap_err();
    assert_ne!(err, "timed out");
    assert_eq!(
        stats(&url, &with_identity(&robot_cert, &robot_key)).await,
        Ok(0)
    );
    // The server refused both handshakes (the clients only see the
    // connection close: TLS 1.3 checks the client's certificate last).
    let failures = Server::sample(&server.scrape(), "humem_tls_handshake_failures_total");
    assert!(failures >= Some(2.0), "{failures:?}");
}

#[tokio::test(flavor = "multi_thread")]
async fn a_new_certificate_is_served_without_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let old_ca = Authority::new("Old CA");
    let old_ca_file = old_ca.write_ca(dir.path(), "old-ca");
    let (cert, key) = old_ca.issue(dir.path(), "server", &["localhost", "127.0.0.1"]);
    let server = start(dir.path(), &tls_env(&cert, &key));
    let url = https(&server);
    assert_eq!(stats(&url, &trusting(&old_ca_file)).await, Ok(0));
    let reloads = |result: &str| {
        Server::sample(
            &server.scrape(),
            &format!("humem_tls_reloads_total{{result=\"{result}\"}}"),
        )
        .unwrap()
    };

    // A broken key file: the reload fails and the old certificate stays.
    std::fs::write(&key, "not a key").unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    while reloads("error") < 1.0 {
        assert!(Instant::now() < deadline, "the broken key was not noticed");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(stats(&url, &trusting(&old_ca_file)).await, Ok(0));

    // Rotation to a certificate from another CA, as cert-manager would.
    let new_ca = Authority::new("New CA");
    let new_ca_file = new_ca.write_ca(dir.path(), "new-ca");
    new_ca.issue(dir.path(), "server", &["localhost", "127.0.0.1"]);
    let rotated = Instant::now();
    while stats(&url, &trusting(&new_ca_file)).await.is_err() {
        assert!(
            rotated.elapsed() < Duration::from_secs(10),
            "the new certificate was not served within 10 s"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(reloads("ok") >= 1.0);
    // New connections no longer get the old certificate.
    let err = stats(&url, &trusting(&old_ca_file)).await.unwrap_err();
    assert!(err.contains("certificate"), "{err}");
}

#[test]
fn a_certificate_that_cannot_be_loaded_stops_the_start_with_the_file_named() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nowhere.crt");
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_humem"))
        .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(dir.path().join("data"))
        .env("HUMEM_PERCEPTION__ENABLED", "false")
        .env("HUMEM_METRICS__ENABLED", "false")
        .env("HUMEM_SERVER__TLS__CERT", &missing)
        .env("HUMEM_SERVER__TLS__KEY", &missing)
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("nowhere.crt"), "{stderr}");
    assert!(stderr.contains("server.tls"), "{stderr}");
}
