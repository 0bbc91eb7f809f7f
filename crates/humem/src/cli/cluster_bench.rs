//! `humem bench cluster`: what cluster mode costs and gives, measured from
//! a client against running replicas (scripts/bench-cluster.sh starts a
//! NATS cluster and the replicas, and kills some while `--failover` runs).
//!
//! - **Replica lag:** robots insert at a fixed rate, each through one
//!   replica; after each acknowledgement every other replica is asked the
//!   keyframe with `min_log_sequence` set to the write's position, so the
//!   answer comes once that replica has applied it. The time from the
//!   acknowledgement to that answer, against the same query on the replica
//!   that took the write, is the lag a reader sees.
//! - **Query throughput** with 1, 2, … replicas: closed-loop clients spread
//!   over the first k replicas, same run.
//! - **Failover** (`--failover SECONDS`): one writer per replica that moves
//!   to the next replica when a call fails; the longest wait for an
//!   acknowledgement, and afterwards every acknowledged write looked up on
//!   every replica (lost writes are counted, and must be 0).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use hdrhistogram::Histogram;
use parking_lot::Mutex;

use humem_server::client::{ClientCredentials, Connection};
use humem_server::proto;
use humem_server::proto::place_recognition_client::PlaceRecognitionClient;

/// Options of `humem bench cluster`.
#[derive(Debug, Clone, clap::Args)]
pub struct ClusterBench {
    /// The replicas' URLs, comma-separated.
    #[arg(long, value_delimiter = ',', required = true)]
    pub replicas: Vec<String>,
    #[command(flatten)]
    pub tls: ClientCredentials,
    /// Robots inserting in the lag run.
    #[arg(long, default_value_t = 8)]
    pub robots: usize,
    /// Keyframes per second per robot in the lag run.
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
    /// Seconds of the lag run.
    #[arg(long, default_value_t = 20.0)]
    pub duration: f64,
    /// Descriptor length of the synthetic keyframes.
    #[arg(long, default_value_t = 256)]
    pub dim: usize,
    /// Concurrent query clients in the throughput run.
    #[arg(long, default_value_t = 8)]
    pub clients: usize,
    /// Seconds per replica count in the throughput run.
    #[arg(long, default_value_t = 10.0)]
    pub query_seconds: f64,
    /// Instead of the lag and throughput runs: write for this many seconds
    /// while replicas and NATS nodes are killed, then count lost writes.
    #[arg(long)]
    pub failover: Option<f64>,
}

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 600_000_000, 3).expect("valid bounds")
}

/// A unit-length pseudo-random descriptor.
fn descriptor(dim: usize, seed: u64) -> Vec<f32> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut v: Vec<f32> = (0..dim)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        })
        .collect();
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.iter_mut().for_each(|x| *x /= norm);
    v
}

fn keyframe(robot: &str, id: u64, dim: usize) -> proto::Keyframe {
    let seed = id ^ hash(robot);
    super::load::keyframe(
        robot,
        "bench",
        id,
        id as f64 / 10.0,
        [id as f64, 0.0, 0.0],
        proto::keyframe::Content::Features(proto::Features {
            global_descriptor: descriptor(dim, seed),
            ..Default::default()
        }),
    )
}

fn hash(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    })
}

fn query(robot: &str, id: u64, at: u64) -> proto::QueryRequest {
    proto::QueryRequest {
        robot_id: robot.into(),
        session_id: "bench".into(),
        keyframe_id: Some(id),
        min_log_sequence: Some(at),
        top_n: Some(1),
        threshold: Some(0.0),
        ..Default::default()
    }
}

fn ms(h: &Histogram<u64>, q: f64) -> f64 {
    h.value_at_quantile(q) as f64 / 1000.0
}

/// Runs the benchmark and prints its tables.
pub async fn run(args: ClusterBench) -> anyhow::Result<()> {
    let mut clients = Vec::new();
    for url in &args.replicas {
        clients.push(
            humem_server::client::connect(url, &args.tls)
                .await
                .with_context(|| format!("connecting to {url}"))?,
        );
    }
    if let Some(seconds) = args.failover {
        return failover(&args, &clients, seconds).await;
    }
    lag(&args, &clients).await?;
    throughput(&args, &clients).await
}

/// Inserts at `rate` per robot; after each acknowledgement, asks every
/// other replica for the keyframe at the write's position.
async fn lag(
    args: &ClusterBench,
    clients: &[PlaceRecognitionClient<Connection>],
) -> anyhow::Result<()> {
    let n = clients.len();
    let insert = Arc::new(Mutex::new(histogram()));
    let visible = Arc::new(Mutex::new(histogram()));
    let local = Arc::new(Mutex::new(histogram()));
    let errors = Arc::new(Mutex::new(Vec::<String>::new()));
    let period = Duration::from_secs_f64(1.0 / args.rate);
    let ticks = (args.duration * args.rate) as u64;
    let mut robots = Vec::new();
    for r in 0..args.robots {
        let clients = clients.to_vec();
        let (insert, visible, local, errors) = (
            insert.clone(),
            visible.clone(),
            local.clone(),
            errors.clone(),
        );
        let dim = args.dim;
        robots.push(tokio::spawn(async move {
            let robot = format!("lag-{r}");
            let writer = r % n;
            let mut interval = tokio::time::interval(period);
            interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut probes = Vec::new();
            for id in 0..ticks {
                interval.tick().await;
                let started = Instant::now();
                let reply = clients[writer]
                    .clone()
                    .insert(proto::InsertRequest {
                        keyframe: Some(keyframe(&robot, id, dim)),
                    })
                    .await;
                let acked = Instant::now();
                let sequence = match reply {
                    Ok(reply) => reply.into_inner().log_sequence,
                    Err(status) => {
                        errors.lock().push(format!("insert: {status}"));
                        continue;
                    }
                };
                insert.lock().record(started.elapsed().as_micros() as u64)?;
                for (j, client) in clients.iter().enumerate() {
                    let mut client = client.clone();
                    let robot = robot.clone();
                    let target = if j == writer {
                        local.clone()
                    } else {
                        visible.clone()
                    };
                    let errors = errors.clone();
                    probes.push(tokio::spawn(async move {
                        match client.query(query(&robot, id, sequence)).await {
                            Ok(_) => {
                                let _ = target.lock().record(acked.elapsed().as_micros() as u64);
                            }
                            Err(status) => errors.lock().push(format!("query: {status}")),
                        }
                    }));
                }
            }
            for probe in probes {
                let _ = probe.await;
            }
            anyhow::Ok(())
        }));
    }
    for robot in robots {
        robot.await??;
    }
    let (insert, visible, local) = (insert.lock(), visible.lock(), local.lock());
    println!(
        "\nReplica lag: {} robots x {} Hz for {} s through {n} replicas ({} inserts)\n",
        args.robots,
        args.rate,
        args.duration,
        insert.len()
    );
    println!("| ms | p50 | p99 | max |\n| --- | --- | --- | --- |");
    for (name, h) in [
        (
            "insert, until acknowledged (published, stored by JetStream, applied on its replica)",
            &*insert,
        ),
        (
            "after the acknowledgement: answered by the same replica",
            &*local,
        ),
        (
            "after the acknowledgement: answered by another replica (its lag)",
            &*visible,
        ),
    ] {
        println!(
            "| {name} | {:.2} | {:.2} | {:.2} |",
            ms(h, 0.5),
            ms(h, 0.99),
            h.max() as f64 / 1000.0
        );
    }
    report_errors(&errors.lock());
    Ok(())
}

/// Closed-loop query clients over the first k replicas, k = 1..=n.
async fn throughput(
    args: &ClusterBench,
    clients: &[PlaceRecognitionClient<Connection>],
) -> anyhow::Result<()> {
    let keyframes = (args.duration * args.rate) as u64;
    println!(
        "\nQuery throughput: {} closed-loop clients, {} s per row, stored-keyframe queries on a store of {} keyframes\n",
        args.clients,
        args.query_seconds,
        keyframes * args.robots as u64
    );
    println!("| replicas | queries/s | vs 1 replica | p50 ms | p99 ms | errors |\n| --- | --- | --- | --- | --- | --- |");
    let mut base = None;
    for k in 1..=clients.len() {
        let stop = Arc::new(AtomicBool::new(false));
        let latency = Arc::new(Mutex::new(histogram()));
        let errors = Arc::new(Mutex::new(Vec::<String>::new()));
        let mut tasks = Vec::new();
        for c in 0..args.clients {
            let mut client = clients[c % k].clone();
            let (stop, latency, errors) = (stop.clone(), latency.clone(), errors.clone());
            let robots = args.robots.max(1);
            tasks.push(tokio::spawn(async move {
                let mut i = c as u64;
                while !stop.load(Ordering::Relaxed) {
                    i = i
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let robot = format!("lag-{}", (i >> 33) as usize % robots);
                    let id = (i >> 20) % keyframes.max(1);
                    let started = Instant::now();
                    match client.query(query(&robot, id, 0)).await {
                        Ok(_) => {
                            let _ = latency.lock().record(started.elapsed().as_micros() as u64);
                        }
                        Err(status) => errors.lock().push(status.to_string()),
                    }
                }
            }));
        }
        tokio::time::sleep(Duration::from_secs_f64(args.query_seconds)).await;
        stop.store(true, Ordering::Relaxed);
        for task in tasks {
            task.await?;
        }
        let latency = latency.lock();
        let rate = latency.len() as f64 / args.query_seconds;
        let base = *base.get_or_insert(rate);
        println!(
            "| {k} | {rate:.0} | {:.2}x | {:.2} | {:.2} | {} |",
            rate / base,
            ms(&latency, 0.5),
            ms(&latency, 0.99),
            errors.lock().len()
        );
    }
    Ok(())
}

/// One writer per replica at 20 Hz, moving to the next replica when a
/// call fails; then every acknowledged write is looked up everywhere.
async fn failover(
    args: &ClusterBench,
    clients: &[PlaceRecognitionClient<Connection>],
    seconds: f64,
) -> anyhow::Result<()> {
    let n = clients.len();
    let deadline = Instant::now() + Duration::from_secs_f64(seconds);
    let mut writers = Vec::new();
    for w in 0..n {
        let urls = args.replicas.clone();
        let tls = args.tls.clone();
        let dim = args.dim;
        writers.push(tokio::spawn(async move {
            let robot = format!("failover-{w}");
            let mut target = w;
            let mut acked = Vec::new();
            let mut failures = 0usize;
            let mut longest = Duration::ZERO;
            let mut last = Instant::now();
            let mut id = 0u64;
            while Instant::now() < deadline {
                let url = &urls[target];
                let attempt = async {
                    let mut client = humem_server::client::connect(url, &tls)
                        .await
                        .map_err(|e| tonic::Status::unavailable(e.to_string()))?;
                    client
                        .insert(proto::InsertRequest {
                            keyframe: Some(keyframe(&robot, id, dim)),
                        })
                        .await
                };
                match tokio::time::timeout(Duration::from_secs(15), attempt).await {
                    Ok(Ok(reply)) => {
                        acked.push((id, reply.into_inner().log_sequence));
                        longest = longest.max(last.elapsed());
                        last = Instant::now();
                        id += 1;
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                    _ => {
                        failures += 1;
                        target = (target + 1) % urls.len();
                        tokio::time::sleep(Duration::from_millis(20)).await;
                    }
                }
            }
            (robot, acked, failures, longest)
        }));
    }
    let mut results = Vec::new();
    for writer in writers {
        results.push(writer.await?);
    }
    let newest = results
        .iter()
        .flat_map(|r| r.1.iter().map(|a| a.1))
        .max()
        .unwrap_or(0);
    let mut lost = 0usize;
    let mut looked_up = 0usize;
    let mut unreachable = Vec::new();
    for (j, client) in clients.iter().enumerate() {
        let mut client = client.clone();
        // The replica may have restarted: ask again until it answers.
        let mut ready = false;
        for _ in 0..300 {
            if client.stats(proto::StatsRequest {}).await.is_ok() {
                ready = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        if !ready {
            unreachable.push(args.replicas[j].clone());
            continue;
        }
        for (robot, acked, _, _) in &results {
            for &(id, _) in acked {
                let mut request = tonic::Request::new(query(robot, id, newest));
                request.set_timeout(Duration::from_secs(30));
                match client.query(request).await {
                    Ok(_) => looked_up += 1,
                    Err(status) if status.code() == tonic::Code::NotFound => lost += 1,
                    Err(status) => {
                        anyhow::bail!("looking up {robot} {id} on {}: {status}", args.replicas[j])
                    }
                }
            }
        }
    }
    let acked: usize = results.iter().map(|r| r.1.len()).sum();
    let failures: usize = results.iter().map(|r| r.2).sum();
    let longest = results.iter().map(|r| r.3).max().unwrap_or_default();
    println!("\nFailover: {n} writers at 20 Hz for {seconds} s\n");
    println!("| acknowledged writes | failed attempts | longest wait for an acknowledgement | looked up on every replica | acknowledged writes lost |");
    println!("| --- | --- | --- | --- | --- |");
    println!(
        "| {acked} | {failures} | {:.0} ms | {looked_up} | {lost} |",
        longest.as_secs_f64() * 1000.0
    );
    if !unreachable.is_empty() {
        println!(
            "\nnot reachable afterwards (not checked): {}",
            unreachable.join(", ")
        );
    }
    if lost > 0 {
        anyhow::bail!("{lost} acknowledged writes were lost");
    }
    Ok(())
}

fn report_errors(errors: &[String]) {
    if errors.is_empty() {
        return;
    }
    println!("\n{} errors; first: {}", errors.len(), errors[0]);
}
