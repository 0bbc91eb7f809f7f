//! `humem serve`: opens the store, starts the gRPC server with the standard
//! health and reflection services, and shuts down cleanly on SIGINT/SIGTERM
//! (stop accepting, let in-flight requests finish, flush the store).
//!
//! [`serve_watching`] runs the stages in order, each a function with one
//! job: open the store, the models, the authenticator and the pipeline
//! (`open`), build the router and serve until stopped
//! (`serve_until_stopped`, with the metrics endpoint, the bind and the
//! replica's readiness watch beside it), and shut down (`shut_down`).

use anyhow::Context;
use tokio::net::TcpListener;
use tonic::transport::server::TcpIncoming;

use crate::api::validate::Limits;
use crate::api::PlaceRecognitionService;
use crate::auth::Authenticator;
use crate::config::Config;
use crate::metrics;
use crate::pipeline::admission::QueryAdmission;
use crate::pipeline::latest_wins::LatestWins;
use crate::pipeline::Pipeline;
use crate::proto::place_recognition_server::PlaceRecognitionServer;
use crate::tls::ReloadingTls;
use humem_cluster::Replica;
use humem_perception::Perception;
use humem_store::{Store, StoreOptions};

/// Runs the service until a shutdown signal.
pub async fn serve(config: Config) -> anyhow::Result<()> {
    serve_watching(config, None).await
}

/// [`serve`], re-reading the access rules (`auth.groups`,
/// `auth.certificate_admins`) from `rules_file` whenever it changes, through
/// its [`RulesSource`](crate::auth::RulesSource) (the configuration loaded
/// again as at start).
pub async fn serve_watching(
    config: Config,
    rules_file: Option<(std::path::PathBuf, crate::auth::RulesSource)>,
) -> anyhow::Result<()> {
    let Opened {
        store,
        pipeline,
        auth,
        replica,
    } = open(&config, rules_file).await?;
    serve_until_stopped(&config, &store, pipeline, &auth, replica.clone()).await?;
    shut_down(&store, replica.as_ref()).await
}

/// What the service runs on, once opened.
struct Opened {
    store: Store,
    pipeline: Pipeline,
    auth: Authenticator,
    /// This server's replica of the cluster, in cluster mode.
    replica: Option<Replica>,
}

/// Opens the store and loads the models side by side, starts the
/// authenticator, joins the cluster in cluster mode, and builds the
/// request pipeline on them. Refuses a configuration that would expose
/// the service, or a descriptor model the store cannot hold.
async fn open(
    config: &Config,
    rules_file: Option<(std::path::PathBuf, crate::auth::RulesSource)>,
) -> anyhow::Result<Opened> {
    std::fs::create_dir_all(&config.store.data_dir).with_context(|| {
        format!(
            "creating data directory {}",
            config.store.data_dir.display()
        )
    })?;
    // One pool for every query's scan (rayon's global pool): concurrent
    // queries share its threads instead of each taking every core.
    if config.query.scan_threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(config.query.scan_threads)
            .thread_name(|i| format!("humem-scan-{i}"))
            .build_global()
            .context("starting the scan threads (query.scan_threads)")?;
    }
    // The store and the models load side by side: each takes seconds on a
    // large store or a cold model cache, and they share nothing.
    let store_options = StoreOptions {
        dim: config.store.descriptor_dim,
        queue_capacity: config.store.write_queue,
        snapshot_every: config.store.snapshot_every,
        min_free_bytes: config.store.min_free_bytes,
        descriptors_to_file: config.store.descriptors_to_file(config.vpr.scan),
        cache_bytes: config.store.cache_bytes,
        neighbour_graph: config.store.neighbour_graph,
        neighbour_graph_length: config.store.neighbour_graph_length,
        map_graphs_from: if config.store.map_graphs && !config.vpr.exact {
            config.vpr.approximate_from
        } else {
            0
        },
    };
    // Cluster mode: a store the write log no longer reaches (new, or away
    // longer than the log keeps entries) starts from the newest snapshot.
    if config.cluster.enabled {
        check_nats_exposure(config)?;
        humem_cluster::snapshots::restore_if_behind(
            &config.cluster,
            &config.store.data_dir,
            std::sync::Arc::new(metrics::cluster::PrometheusCluster),
        )
        .await
        .context("restoring the store from the cluster's newest snapshot")?;
    }
    let data_dir = config.store.data_dir.clone();
    let opening = tokio::task::spawn_blocking(move || {
        Store::open_with(&data_dir, store_options, metrics::queue_observer())
    });
    let perception = load_perception(config).await?;
    let store = opening
        .await
        .context("opening the store")?
        .with_context(|| format!("opening the store in {}", config.store.data_dir.display()))?;
    if let Some(perception) = &perception {
        descriptor_fits_store(perception, config, store.index().dim())?;
    }
    let auth = Authenticator::start(&config.auth, &config.server.tls, rules_file)
        .context("loading the token file (auth.tokens_file)")?;
    check_exposure(config, auth.enabled())?;
    metrics::init();
    let replica = join_cluster(config, &store).await?;
    let pipeline = Pipeline::new(
        store.clone(),
        config.vpr.clone(),
        perception,
        LatestWins::new(config.query.pending_per_client),
        QueryAdmission::new(
            match config.query.concurrent_scans {
                // The scan pool is built above: one more than its threads.
                0 => rayon::current_num_threads() + 1,
                n => n,
            },
            std::time::Duration::from_millis(config.query.max_wait_ms),
        ),
        replica.clone(),
    )
    .with_keyframe_quota(config.quotas.max_keyframes_per_robot);
    Ok(Opened {
        store,
        pipeline,
        auth,
        replica,
    })
}

/// The perception models, loaded on the blocking pool; `None` when
/// perception is disabled.
async fn load_perception(config: &Config) -> anyhow::Result<Option<Perception>> {
    if !config.perception.enabled {
        tracing::warn!("perception disabled: requests with images will be refused");
        return Ok(None);
    }
    let perception_config = config.perception.clone();
    let top_k = config.store.scene_top_k;
    let perception = tokio::task::spawn_blocking(move || {
        Perception::load_observed(&perception_config, top_k, metrics::queue_observer())
    })
        .await
        .context("loading the perception models")?
        .context("loading the perception models (`humem models check` shows what each model takes and gives; perception.enabled = false serves precomputed features only)")?;
    Ok(Some(perception))
}

/// Cluster mode: joins before serving, and returns only once this replica
/// has applied every write the log held when it joined. `None` outside
/// cluster mode.
async fn join_cluster(config: &Config, store: &Store) -> anyhow::Result<Option<Replica>> {
    if !config.cluster.enabled {
        return Ok(None);
    }
    let replica = Replica::start(
        config.cluster.clone(),
        store.clone(),
        std::sync::Arc::new(metrics::cluster::PrometheusCluster),
    )
    .await
    .context("joining the cluster (cluster.*)")?;
    replica
        .catch_up()
        .await
        .context("catching up with the write log")?;
    Ok(Some(replica))
}

/// The API service on `pipeline`, with the request limits and the access
/// policy, as a gRPC server of the configured message size.
fn api_server(
    config: &Config,
    pipeline: Pipeline,
    auth: &Authenticator,
) -> PlaceRecognitionServer<PlaceRecognitionService> {
    let limits = Limits {
        scene_top_k: config.store.scene_top_k,
        min_frame_gap: config.query.min_frame_gap,
        top_n: config.vpr.max_candidates,
    };
    let service = PlaceRecognitionService::new(
        pipeline,
        limits,
        crate::api::service::Policy {
            auth: auth.clone(),
            quotas: crate::quota::Quotas::new(&config.quotas),
        },
    );
    let max = config.server.max_message_bytes;
    PlaceRecognitionServer::new(service)
        .max_decoding_message_size(max)
        .max_encoding_message_size(max)
}

/// Builds the gRPC router (the API, health and reflection), records the
/// store in the metrics and starts their endpoint, binds the port and
/// serves until a stop signal, then lets in-flight requests finish.
async fn serve_until_stopped(
    config: &Config,
    store: &Store,
    pipeline: Pipeline,
    auth: &Authenticator,
    replica: Option<Replica>,
) -> anyhow::Result<()> {
    let api = api_server(config, pipeline, auth);
    let (health, health_service) = tonic_health::server::health_reporter();
    health
        .set_serving::<PlaceRecognitionServer<PlaceRecognitionService>>()
        .await;
    // Reflection in both versions: `v1` for grpcurl and current clients,
    // `v1alpha` for the many tools (Python's grpcio-reflection among them)
    // that still speak only that one.
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(crate::proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let reflection_v1 = reflection()
        .build_v1()
        .context("building the reflection service (v1)")?;
    let reflection_v1alpha = reflection()
        .build_v1alpha()
        .context("building the reflection service (v1alpha)")?;

    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    // True from the moment the gRPC port is open until shutdown begins.
    let (serving_tx, serving_rx) = tokio::sync::watch::channel(false);
    metrics::store_opened(store);
    let point = store
        .index()
        .operating_point(&config.vpr, humem_core::verdict::unix_now());
    metrics::OPERATING_THRESHOLD.set(f64::from(point.threshold));
    if config.metrics.enabled {
        let mut stop = stop_rx.clone();
        let addr = metrics::serve(
            config.metrics.listen,
            store.clone(),
            serving_rx,
            async move {
                let _ = stop.changed().await;
            },
        )
        .await?;
        tracing::info!(%addr, "metrics on /metrics");
        println!("humem metrics on {addr}");
    }
    let (listener, tls) = bind(config).await?;
    let local = listener.local_addr()?;
    tracing::info!(
        %local,
        tls = tls.is_some(),
        credentials = auth.enabled(),
        mutual_tls = tls.is_some() && config.server.tls.client_ca.is_some(),
        data_dir = %config.store.data_dir.display(),
        "humem serving"
    );
    // Before the line below: a stop from then on shuts down cleanly.
    let stop_requested = shutdown_signal();
    // One plain line on stdout, for scripts and tests that asked for port 0.
    println!("humem listening on {local}");
    let _ = serving_tx.send(true);
    if let Some(replica) = replica {
        unready_when_halted(replica, serving_tx.clone());
    }

    let router = tonic::transport::Server::builder()
        // Outermost, so that it records the code the client receives.
        .layer(crate::api::rpc_metrics::RpcMetricsLayer)
        .layer(tower::util::MapResponseLayer::new(
            crate::api::transport_status::map_transport_status,
        ))
        .add_service(health_service)
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .add_service(api);
    let shutdown = async move {
        stop_requested.await;
        tracing::info!("shutdown requested: finishing in-flight requests");
        let _ = serving_tx.send(false);
        let _ = stop_tx.send(true);
        health
            .set_not_serving::<PlaceRecognitionServer<PlaceRecognitionService>>()
            .await;
    };
    match tls {
        Some(tls) => {
            router
                .serve_with_incoming_shutdown(crate::tls::TlsIncoming::new(listener, tls), shutdown)
                .await
        }
        // TCP_NODELAY: without it, small answers wait ~40 ms for delayed
        // ACKs (Nagle), which `humem load` showed on every call.
        None => {
            router
                .serve_with_incoming_shutdown(
                    TcpIncoming::from(listener).with_nodelay(Some(true)),
                    shutdown,
                )
                .await
        }
    }
    .context("running the gRPC server")?;
    Ok(())
}

/// Loads the TLS certificate where configured and binds the gRPC port.
/// TLS first: a certificate that cannot be loaded stops the start before
/// the port is bound.
async fn bind(config: &Config) -> anyhow::Result<(TcpListener, Option<ReloadingTls>)> {
    let tls = if config.server.tls.enabled() {
        Some(
            ReloadingTls::start(config.server.tls.clone())
                .context("loading the TLS certificate (server.tls)")?,
        )
    } else {
        None
    };
    let listener = TcpListener::bind(config.server.listen)
        .await
        .with_context(|| format!("binding {}", config.server.listen))?;
    Ok((listener, tls))
}

/// A replica that stopped applying the log answers from a store that
/// grows stale: it is no longer ready, so a load balancer moves on. Checks
/// every second until then, or until the server stops.
fn unready_when_halted(replica: Replica, serving: tokio::sync::watch::Sender<bool>) {
    tokio::spawn(async move {
        loop {
            tokio::time::sleep(std::time::Duration::from_secs(1)).await;
            if replica.halted().is_some() {
                let _ = serving.send(false);
                return;
            }
            if serving.is_closed() {
                return;
            }
        }
    });
}

/// After the server stopped: leaves the cluster, flushes the store, and
/// writes an index snapshot (only logged when it fails).
async fn shut_down(store: &Store, replica: Option<&Replica>) -> anyhow::Result<()> {
    if let Some(replica) = replica {
        replica.shutdown().await;
    }
    store.flush().context("flushing the store at shutdown")?;
    // A current snapshot lets the next start skip the journal replay; the
    // store is complete without it, so a failure is only logged.
    let snapshotting = store.clone();
    match tokio::task::spawn_blocking(move || snapshotting.snapshot()).await {
        Ok(Err(e)) => tracing::warn!(error = %e, "index snapshot at shutdown failed"),
        Err(e) => tracing::warn!(error = %e, "index snapshot at shutdown failed"),
        Ok(Ok(_)) => {}
    }
    tracing::info!("humem stopped");
    Ok(())
}

/// Checks the descriptor model's length against the store's (`dim`, 0:
/// not fixed yet), where the graph fixes it. Against `store.descriptor_dim`
/// a mismatch is a configuration error and refuses the start. Against the
/// length the stored keyframes fixed it is only a warning: a running
/// server takes keyframes with precomputed descriptors of any length into
/// an empty store, and its restart must take the store it wrote; inserts
/// with images are then refused one by one, as they were before the
/// restart. The models' own graph checks ran as they loaded.
fn descriptor_fits_store(
    perception: &Perception,
    config: &Config,
    dim: usize,
) -> anyhow::Result<()> {
    let (Some(len), true) = (perception.descriptor_len(), dim > 0) else {
        return Ok(());
    };
    let configured = config.store.descriptor_dim > 0;
    let source = if configured {
        "store.descriptor_dim".to_string()
    } else {
        format!(
            "the store in {}; start a new data directory when the descriptor model changes",
            config.store.data_dir.display()
        )
    };
    let expected = [humem_perception::check::Expected { len: dim, source }];
    let m = &config.perception.descriptor;
    let fits = humem_perception::check::graph::lengths_fit(
        "perception.descriptor",
        &m.output,
        len,
        &format!("[N, {len}] in {}", m.model.display()),
        &expected,
    )
    .context("checking the perception models against the store (humem models check says more)");
    match fits {
        Err(e) if !configured => {
            tracing::warn!(
                "{e:#}: keyframes with precomputed {dim}-value descriptors are taken, \
                 keyframes with images are refused"
            );
            Ok(())
        }
        other => other,
    }
}

/// Refuses to serve beyond this machine without TLS and credentials,
/// unless `server.allow_insecure_network` says so.
pub fn check_exposure(config: &Config, credentials: bool) -> anyhow::Result<()> {
    check_nats_exposure(config)?;
    let listen = config.server.listen;
    let tls = config.server.tls.enabled();
    if listen.ip().is_loopback() || (tls && credentials) {
        return Ok(());
    }
    let missing = match (tls, credentials) {
        (false, false) => "TLS and credentials",
        (false, true) => "TLS",
        _ => "credentials",
    };
    if config.server.allow_insecure_network {
        tracing::warn!(%listen, missing, "serving a network address without TLS or credentials (server.allow_insecure_network)");
        return Ok(());
    }
    anyhow::bail!(
        "refusing to serve {listen} without {missing}: anyone who reaches it could write, read and wipe every robot's maps. \
         Set server.tls.cert and server.tls.key, and auth.tokens_file or server.tls.client_ca; \
         or listen on 127.0.0.1; or set server.allow_insecure_network = true behind a proxy that does both"
    )
}

/// Refuses to reach NATS beyond this machine without TLS and credentials
/// (whoever can publish to the write log can change every replica), unless
/// `server.allow_insecure_network` says so.
fn check_nats_exposure(config: &Config) -> anyhow::Result<()> {
    let cluster = &config.cluster;
    if !cluster.enabled || cluster.nats_is_local() {
        return Ok(());
    }
    let missing = match (cluster.tls.enabled(), cluster.auth.enabled()) {
        (true, true) => return Ok(()),
        (false, false) => "TLS (cluster.tls) and credentials (cluster.auth)",
        (false, true) => "TLS (cluster.tls)",
        (true, false) => "credentials (cluster.auth)",
    };
    if config.server.allow_insecure_network {
        tracing::warn!(missing, "reaching NATS over the network without TLS or credentials (server.allow_insecure_network)");
        return Ok(());
    }
    anyhow::bail!(
        "refusing to reach NATS at {} without {missing}: whoever can publish to the write log changes every replica's store. \
         Configure them, or set server.allow_insecure_network = true on a network only the cluster uses",
        cluster.nats_urls.join(",")
    )
}

/// Ctrl-C or SIGTERM. The handlers are installed when this is called, not
/// when the future is first polled: the server calls it before it says it
/// is listening, so a stop that arrives right after start (a supervisor, a
/// test) is a clean shutdown, not the signal's default death.
fn shutdown_signal() -> impl std::future::Future<Output = ()> {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        let streams = [SignalKind::interrupt(), SignalKind::terminate()].map(signal);
        async move {
            let [interrupt, terminate] = streams;
            let wait = |stream: std::io::Result<tokio::signal::unix::Signal>| async move {
                match stream {
                    Ok(mut s) => {
                        s.recv().await;
                    }
                    Err(e) => {
                        tracing::warn!(error = %e, "cannot listen for a stop signal");
                        std::future::pending::<()>().await
                    }
                }
            };
            tokio::select! {
                _ = wait(interrupt) => {},
                _ = wait(terminate) => {},
            }
        }
    }
    #[cfg(not(unix))]
    async {
        let _ = tokio::signal::ctrl_c().await;
    }
}
