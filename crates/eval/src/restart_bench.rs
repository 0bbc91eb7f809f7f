//! `humem bench restart`: how long the store takes to open on a large
//! store, from its index snapshot plus the journal against rebuilding the
//! index from every record in sled (the baseline, and what a store without
//! a usable snapshot does), in the same run on the same store.
//!
//! Each size's store is written through the store's own writer (the
//! service's write path, group commit and journal included), with the
//! synthetic fleet of `humem bench scan`. A snapshot is taken, then
//! `--replay` more keyframes are inserted and the store is dropped without
//! another: what a SIGKILL leaves. Both opens then read files the kernel
//! has just cached, as a restart on the same machine does; a cold disk adds
//! its read time to both.
//!
//! With `--neighbour-graph` the store keeps its neighbour graph as the
//! server does (`store.neighbour_graph`): the writer adds every keyframe
//! to it, the snapshot saves it, and the snapshot open loads it; the
//! replayed keyframes wait to enter it, and the time the writer then takes
//! to add them is reported apart. That open is timed against the same
//! snapshot opened without the graph, in the same run; the cluster export carries
//! the graph and the restored store loads it. The tree open stays without
//! the graph (with it, it would build one from every row: minutes).

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{ensure, Context};

use humem_store::graph_file::GraphSource;
use humem_store::{IndexSource, Mutation, Store, StoreOptions};

use crate::scan_bench::{timed, SyntheticFleet};

/// Options of `humem bench restart`.
#[derive(Debug, Clone, clap::Args)]
pub struct RestartBench {
    /// Store sizes, in keyframes.
    #[arg(long, value_delimiter = ',', default_values_t = [100_000, 1_000_000])]
    pub rows: Vec<usize>,
    /// Descriptor length.
    #[arg(long, default_value_t = 512)]
    pub dim: usize,
    /// Keyframes inserted after the snapshot, replayed from the journal.
    #[arg(long, default_value_t = 10_000)]
    pub replay: usize,
    /// Robots sharing the store.
    #[arg(long, default_value_t = 8)]
    pub robots: usize,
    /// Directory the stores are made in (a temporary directory inside
    /// it, removed afterwards).
    #[arg(long, default_value_os_t = std::env::temp_dir())]
    pub dir: PathBuf,
    /// Keep the neighbour graph, as the server does by default.
    #[arg(long)]
    pub neighbour_graph: bool,
}

/// Keyframes per insert while the store is built.
const BATCH: usize = 1000;

/// One size's figures.
struct Row {
    rows: usize,
    insert_rate: f64,
    tree: Duration,
    snapshot: Duration,
    replayed: usize,
    written: Duration,
    synced: Duration,
    bytes: u64,
    /// The cluster snapshot's export (writes wait meanwhile), its size,
    /// and a new replica's restore from it followed by the open.
    export: Duration,
    export_bytes: u64,
    restore: Duration,
    /// With the graph: the same snapshot opened without it, the graph's
    /// file size and its memory.
    graph: Option<GraphFigures>,
}

/// What the neighbour graph adds to a restart.
struct GraphFigures {
    snapshot_without: Duration,
    /// From the end of the open until the writer had added the keyframes
    /// the saved graph lacked (queries scored them exactly meanwhile).
    caught_up: Duration,
    file_bytes: u64,
    memory_bytes: usize,
}

/// The server's defaults where they matter here: the descriptors leave
/// memory where `store.descriptors = "auto"` would move them (1M × 512:
/// yes; 100k × 512: no), so that the opens include that.
fn options(neighbour_graph: bool) -> StoreOptions {
    let auto = humem_server::config::StoreConfig::default();
    StoreOptions {
        snapshot_every: 0,
        descriptors_to_file: auto.descriptors_to_file(humem_core::vpr::params::ScanMode::Auto),
        neighbour_graph,
        map_graphs_from: if neighbour_graph {
            humem_core::vpr::params::APPROXIMATE_FROM
        } else {
            0
        },
        ..StoreOptions::default()
    }
}

fn open(dir: &Path, neighbour_graph: bool) -> anyhow::Result<Store> {
    Store::open_with(
        dir,
        options(neighbour_graph),
        humem_core::observe::unobserved(),
    )
    .with_context(|| format!("opening the store in {}", dir.display()))
}

/// Gives a dropped store's writer thread time to flush and let go of the
/// directory, so that the timed open does not wait for it.
fn settle() {
    std::thread::sleep(Duration::from_secs(1));
}

/// Opens the store once its previous handle's threads have let go of it.
fn reopen(dir: &Path, neighbour_graph: bool) -> anyhow::Result<Store> {
    for _ in 0..250 {
        match Store::open_with(
            dir,
            options(neighbour_graph),
            humem_core::observe::unobserved(),
        ) {
            Err(humem_store::StoreError::Open { .. }) => {
                std::thread::sleep(Duration::from_millis(20))
            }
            other => return other.context("reopening the store"),
        }
    }
    open(dir, neighbour_graph)
}

/// Runs the benchmark and prints the table.
pub async fn restart(args: RestartBench) -> anyhow::Result<()> {
    ensure!(args.dim > 0, "--dim must be at least 1");
    ensure!(args.robots > 0, "--robots must be at least 1");
    let mut table = Vec::new();
    for &rows in &args.rows {
        table.push(measure(&args, rows).await?);
    }
    print(&args, &table);
    Ok(())
}

/// A store written for the benchmark: its snapshot report and insert rate.
struct Written {
    report: humem_store::SnapshotReport,
    insert_rate: f64,
}

/// Writes `rows` keyframes through the store's writer, takes a snapshot,
/// writes `args.replay` more and drops the store without another.
async fn write_store(args: &RestartBench, dir: &Path, rows: usize) -> anyhow::Result<Written> {
    eprintln!("bench restart: writing a store of {rows} x {}", args.dim);
    let mut fleet = SyntheticFleet::new(rows + args.replay, args.dim, args.robots);
    let store = open(dir, args.neighbour_graph)?;
    let insert = |store: &Store, range: std::ops::Range<usize>, fleet: &mut SyntheticFleet| {
        let keyframes = range.map(|i| fleet.keyframe(i)).collect();
        let store = store.clone();
        async move { store.apply(Mutation::Insert(keyframes)).await }
    };
    let started = std::time::Instant::now();
    for start in (0..rows).step_by(BATCH) {
        insert(&store, start..(start + BATCH).min(rows), &mut fleet).await?;
    }
    let insert_rate = rows as f64 / started.elapsed().as_secs_f64();
    // The writer adds keyframes to the graph behind the inserts; a server
    // that has run a while has added them all before its snapshot.
    ensure!(
        store.wait_for_neighbour_graph(Duration::from_secs(4 * 3600)),
        "the graph had not taken the stored keyframes after four hours"
    );
    eprintln!("bench restart: taking a snapshot");
    let report = store
        .snapshot()?
        .context("a new store has a snapshot to write")?;
    for start in (rows..rows + args.replay).step_by(BATCH) {
        insert(
            &store,
            start..(start + BATCH).min(rows + args.replay),
            &mut fleet,
        )
        .await?;
    }
    drop(store);
    settle();
    Ok(Written {
        report,
        insert_rate,
    })
}

/// Today's restart, the baseline of the graph's: the same snapshot and
/// journal opened with the graph's file left unread.
fn open_without_graph(dir: &Path) -> anyhow::Result<Duration> {
    eprintln!("bench restart: opening from the snapshot, without the graph");
    let (took, store) = timed(|| reopen(dir, false));
    ensure!(
        matches!(store?.opened().source, IndexSource::Snapshot { .. }),
        "the store did not open from its snapshot"
    );
    settle();
    Ok(took)
}

/// The graph a snapshot open loaded, checked to hold every keyframe once
/// the writer has added those it lacked.
fn graph_figures(
    store: &Store,
    dir: &Path,
    keyframes: usize,
    snapshot_without: Duration,
) -> anyhow::Result<GraphFigures> {
    ensure!(
        store.opened().graph == Some(GraphSource::Loaded),
        "the snapshot open did not load the graph: {:?}",
        store.opened().graph
    );
    let (caught_up, done) = timed(|| store.wait_for_neighbour_graph(Duration::from_secs(3600)));
    ensure!(
        done,
        "the graph had not taken the replayed keyframes after an hour"
    );
    let index = store.index();
    let held = index
        .neighbour_graph()
        .context("no graph after the snapshot open")?;
    ensure!(
        held.len() == keyframes,
        "the graph holds {} of {keyframes} keyframes",
        held.len()
    );
    Ok(GraphFigures {
        snapshot_without,
        caught_up,
        file_bytes: std::fs::metadata(humem_store::graph_file::path(dir))?.len(),
        memory_bytes: held.memory_bytes(),
    })
}

/// What a cluster snapshot costs: the export on the writer thread (its
/// time and size), and a new replica's restore from it followed by its
/// open, loading the graph the export carries.
async fn export_and_restore(
    store: Store,
    parent: &Path,
    keyframes: usize,
    graph: bool,
) -> anyhow::Result<(Duration, u64, Duration)> {
    eprintln!("bench restart: exporting the store, as a cluster snapshot does");
    let file = parent.join("export.bin");
    let started = std::time::Instant::now();
    let header = store.export(&file).await?;
    let export = started.elapsed();
    ensure!(
        header.keyframes as usize == keyframes,
        "the export misses keyframes"
    );
    let export_bytes = std::fs::metadata(&file)?.len();
    drop(store);
    settle();
    eprintln!("bench restart: restoring a new store from the export");
    let restored_dir = parent.join("restored");
    let (restore, restored) = timed(|| {
        humem_store::export::restore(&restored_dir, &file)?;
        reopen(&restored_dir, graph)
    });
    let restored = restored?;
    ensure!(
        restored.index().len() == keyframes,
        "the restored store differs"
    );
    ensure!(
        !graph || restored.opened().graph == Some(GraphSource::Loaded),
        "the restored store built its graph instead of loading the export's"
    );
    drop(restored);
    std::fs::remove_file(&file)?;
    settle();
    Ok((export, export_bytes, restore))
}

/// The open that rebuilds the index from every record (the snapshot set
/// aside), without the graph.
fn open_from_tree(dir: &Path, keyframes: usize) -> anyhow::Result<Duration> {
    eprintln!("bench restart: opening from the tree");
    let aside = dir.join("bench.snapshot");
    std::fs::rename(humem_store::snapshot::path(dir), &aside)?;
    let (tree, store) = timed(|| reopen(dir, false));
    let store = store?;
    ensure!(
        matches!(store.opened().source, IndexSource::Tree { .. }),
        "the store did not rebuild from the tree"
    );
    ensure!(
        store.index().len() == keyframes,
        "the tree and the snapshot disagree"
    );
    drop(store);
    settle();
    Ok(tree)
}

/// One store size, every open of it.
async fn measure(args: &RestartBench, rows: usize) -> anyhow::Result<Row> {
    let parent = tempfile::tempdir_in(&args.dir)
        .with_context(|| format!("making a store directory in {}", args.dir.display()))?;
    let dir = parent.path();
    let graph = args.neighbour_graph;
    let written = write_store(args, dir, rows).await?;
    let snapshot_without = if graph {
        Some(open_without_graph(dir)?)
    } else {
        None
    };
    eprintln!("bench restart: opening from the snapshot");
    let (snapshot, store) = timed(|| reopen(dir, graph));
    let store = store?;
    let IndexSource::Snapshot { replayed } = store.opened().source else {
        anyhow::bail!(
            "the store did not open from its snapshot: {:?}",
            store.opened().source
        );
    };
    let keyframes = store.index().len();
    ensure!(
        keyframes == rows + args.replay,
        "{keyframes} keyframes after the snapshot open"
    );
    let graph_figures = match snapshot_without {
        Some(without) => Some(graph_figures(&store, dir, keyframes, without)?),
        None => None,
    };
    let (export, export_bytes, restore) =
        export_and_restore(store, parent.path(), keyframes, graph).await?;
    let tree = open_from_tree(dir, keyframes)?;
    Ok(Row {
        rows,
        insert_rate: written.insert_rate,
        tree,
        snapshot,
        replayed,
        written: written.report.written,
        synced: written.report.elapsed,
        bytes: written.report.bytes,
        export,
        export_bytes,
        restore,
        graph: graph_figures,
    })
}

fn print(args: &RestartBench, table: &[Row]) {
    println!(
        "Store open, {}-d; ratio against rebuilding from the tree in the same run",
        args.dim
    );
    println!(
        "| keyframes | from the tree | from the snapshot + journal | keys replayed | snapshot written / synced | snapshot size | inserts while building (graph excluded) | cluster export (writes wait) / size | restore from it + open |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for r in table {
        println!(
            "| {} | {:.2} s | {:.2} s ({:.2}x) | {} | {:.2} s / {:.2} s | {:.2} GB | {:.0}/s | {:.2} s / {:.2} GB | {:.2} s |",
            r.rows,
            r.tree.as_secs_f64(),
            r.snapshot.as_secs_f64(),
            r.snapshot.as_secs_f64() / r.tree.as_secs_f64(),
            r.replayed,
            r.written.as_secs_f64(),
            r.synced.as_secs_f64(),
            r.bytes as f64 / 1e9,
            r.insert_rate,
            r.export.as_secs_f64(),
            r.export_bytes as f64 / 1e9,
            r.restore.as_secs_f64(),
        );
    }
    if args.neighbour_graph {
        println!();
        println!("The neighbour graph at the snapshot open: the same snapshot and journal opened without it, in the same run");
        println!("| keyframes | without the graph | with it (loaded) | ratio | replayed keys in the graph after | graph file | graph memory a keyframe |");
        println!("| --- | --- | --- | --- | --- | --- | --- |");
        for r in table {
            let Some(g) = &r.graph else { continue };
            println!(
                "| {} | {:.2} s | {:.2} s | {:.2}x | {:.2} s more | {:.2} GB | {:.0} B |",
                r.rows,
                g.snapshot_without.as_secs_f64(),
                r.snapshot.as_secs_f64(),
                r.snapshot.as_secs_f64() / g.snapshot_without.as_secs_f64(),
                g.caught_up.as_secs_f64(),
                g.file_bytes as f64 / 1e9,
                g.memory_bytes as f64 / (r.rows + r.replayed) as f64,
            );
        }
    }
}
