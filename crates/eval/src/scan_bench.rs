//! `humem bench scan`: what a SCAL-only query costs on a large store,
//! against an exact f32 dot-product scan of the same vectors in the same
//! run.
//!
//! The baseline is what faiss `IndexFlatIP` does for one query on one core:
//! one SIMD dot product per stored row and a top-K heap, nothing else; it
//! reads four bytes per value, so on a large store it runs at the memory
//! bandwidth floor. HuMem's query goes through the service's own query path
//! (`pipeline::query::run`: eligibility, scene modulation, temporal context
//! over two predecessors, calibration) with the exact pass on one core, and
//! the compressed pass on one core and on every core. Every answer of the
//! compressed pass is checked against the exact pass (same keyframes, same
//! scores).
//!
//! The store is synthetic, as a fleet's would be shaped: robots that
//! revisit places (descriptors clustered around place centres, unit
//! length), 16 scene classes per keyframe, tracks of consecutive keyframes.
//! Sizes that do not fit in memory are for a larger machine: 1M × 512 needs
//! about 3 GB.

use std::collections::BinaryHeap;
use std::time::{Duration, Instant};

use anyhow::{ensure, Context};

use humem_core::engine::kernels::dot_f32_wide;
use humem_core::index::Index;
use humem_core::keyframe::{Features, KeyframeKey, Pose, SceneClass, SemanticKeyframe, SessionKey};
use humem_core::synthetic::{place_descriptor, place_of, Rng};
use humem_core::vpr::eligibility::Scope;
use humem_core::vpr::memory::KeyframeMemory;
use humem_core::vpr::params::{Layers, ScanMode, VprParams};
use humem_server::config::Config;
use humem_server::pipeline::query::{self, QueryOutcome};
use humem_server::pipeline::request::{QueryKind, QuerySpec};

/// Options of `humem bench scan`.
#[derive(Debug, Clone, clap::Args)]
pub struct ScanBench {
    /// Store sizes, in keyframes.
    #[arg(long, value_delimiter = ',', default_values_t = [100_000, 1_000_000])]
    pub rows: Vec<usize>,
    /// Descriptor length.
    #[arg(long, default_value_t = 512)]
    pub dim: usize,
    /// Timed queries per store size (each method answers every one).
    #[arg(long, default_value_t = 15)]
    pub queries: usize,
    /// Robots sharing the store.
    #[arg(long, default_value_t = 8)]
    pub robots: usize,
    /// Directory for the descriptor row file of the last pass (a disk,
    /// not a memory file system; default: the system's temporary
    /// directory).
    #[arg(long)]
    pub dir: Option<std::path::PathBuf>,
    /// The scoped case: a fleet of this many robots (0: skip it), each
    /// with two maps, queried over one map, over its own robot's maps and
    /// over every map.
    #[arg(long, default_value_t = 50)]
    pub scoped_robots: usize,
    /// Keyframes per robot in the scoped case.
    #[arg(long, default_value_t = 10_000)]
    pub scoped_keyframes: usize,
    /// The scoped case again after this share of the store was erased at
    /// random (SLAM culling old keyframes on a revisit) and as many new
    /// keyframes inserted, one after the other, as a store that has run
    /// for a long time (0: skip it).
    #[arg(long, default_value_t = 0.3)]
    pub scoped_churn: f64,
}

/// Keyframes per place visit, on average: a robot passes a place in a few
/// keyframes and comes back to it later.
const KEYFRAMES_PER_PLACE: usize = 20;

/// The synthetic store: keyframe `i` of robot `i % robots` sees place
/// `place_of(i)`, its descriptor that place's centre plus noise.
fn store(rows: usize, dim: usize, robots: usize) -> Index {
    let mut index = Index::new(dim);
    let mut fleet = SyntheticFleet::new(rows, dim, robots);
    for i in 0..rows {
        index.upsert(fleet.keyframe(i));
    }
    index
}

/// Keyframes of a synthetic fleet, as [`store`] holds them; also what
/// `humem bench restart` stores.
pub struct SyntheticFleet {
    places: u64,
    dim: usize,
    robots: usize,
    noise: Rng,
}

impl SyntheticFleet {
    /// A fleet of `robots` whose `rows` keyframes revisit places in runs.
    pub fn new(rows: usize, dim: usize, robots: usize) -> Self {
        SyntheticFleet {
            places: (rows / KEYFRAMES_PER_PLACE).max(1) as u64,
            dim,
            robots,
            noise: Rng::new(1),
        }
    }

    /// Distinct places the fleet's keyframes see.
    pub fn places(&self) -> u64 {
        self.places
    }

    /// Keyframe `i`: robot `i % robots`, its `i / robots`-th keyframe.
    pub fn keyframe(&mut self, i: usize) -> SemanticKeyframe {
        let robot = i % self.robots;
        let step = (i / self.robots) as u64;
        // Each robot walks through places in runs of 4 keyframes.
        let place = place_of(self.places, robot as u64, step);
        let descriptor = place_descriptor(self.dim, place, &mut self.noise);
        SemanticKeyframe {
            key: KeyframeKey {
                robot_id: format!("robot-{robot}"),
                session_id: "session".into(),
                keyframe_id: step,
            },
            frame_id: 3 * step,
            timestamp: step as f64 * 0.2,
            map_id: 0,
            pose: Pose::default(),
            features: Features {
                descriptor,
                scene: (0..16)
                    .map(|k| SceneClass {
                        class_id: ((place as usize + 3 * k) % 365) as u32,
                        probability: 0.3 / (1.0 + k as f32),
                    })
                    .collect(),
                objects: Vec::new(),
                appearance: Vec::new(),
            },
        }
    }
}

/// The baseline: one query's exact inner products with every row and the
/// top `k`, the way a flat inner-product index answers.
pub(crate) fn flat_scan(index: &Index, query: &[f32], k: usize) -> Vec<(f32, usize)> {
    let matrix = index.descriptors();
    // Min-heap on score of the best k so far (scores are negated).
    let mut best: BinaryHeap<(std::cmp::Reverse<OrderedScore>, usize)> = BinaryHeap::new();
    for row in 0..matrix.len() {
        let score = dot_f32_wide(query, &matrix.row(row));
        if best.len() < k {
            best.push((std::cmp::Reverse(OrderedScore(score)), row));
        } else if let Some(worst) = best.peek() {
            if score > worst.0 .0 .0 {
                best.pop();
                best.push((std::cmp::Reverse(OrderedScore(score)), row));
            }
        }
    }
    best.into_iter().map(|(s, row)| (s.0 .0, row)).collect()
}

/// An f32 ordered by `total_cmp`, for the heap.
#[derive(Debug, Clone, Copy, PartialEq)]
struct OrderedScore(f32);

impl Eq for OrderedScore {}

impl PartialOrd for OrderedScore {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for OrderedScore {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// A loop-closure query for stored keyframe `keyframe_id` of robot 0: its
/// stored features and two predecessors, every map, SCAL only.
fn spec(keyframe_id: u64, top_n: usize) -> QuerySpec {
    QuerySpec {
        session: SessionKey {
            robot_id: "robot-0".into(),
            session_id: "session".into(),
        },
        map_id: None,
        frame_id: None,
        keyframe_id: Some(keyframe_id),
        observation: None,
        predecessor_ids: Vec::new(),
        scope: Scope::AllMaps,
        readable_robots: None,
        min_frame_gap: 30,
        top_n,
        threshold: Some(0.0),
        layers: Layers::SCAL,
        kind: QueryKind::LoopClosure,
        exact: false,
    }
}

/// What one method's answers look like, for comparing with the exact pass.
fn answer(outcome: &QueryOutcome) -> Vec<(KeyframeKey, f32)> {
    outcome
        .candidates
        .iter()
        .map(|c| (c.key.clone(), c.score))
        .collect()
}

/// `f`'s result and how long it took.
pub(crate) fn timed<T>(f: impl FnOnce() -> T) -> (Duration, T) {
    let started = Instant::now();
    let result = f();
    (started.elapsed(), result)
}

/// The median of `samples` in milliseconds (the harness's one latency
/// summary, [`crate::metrics::latency`]).
pub(crate) fn median_ms(samples: &[Duration]) -> f64 {
    crate::metrics::latency(samples).median_ms
}

/// One store size's figures.
struct Row {
    rows: usize,
    build: Duration,
    flat: f64,
    exact: f64,
    compressed_one: f64,
    compressed_all: f64,
    identical: usize,
    queries: usize,
    /// Resident memory the store added, per keyframe (Linux only).
    per_keyframe: Option<f64>,
    /// The compressed pass with the f32 rows in a file: 1 core, every core.
    file_one: f64,
    file_all: f64,
    /// Its answers equal to the exact pass's (with the rows in memory).
    file_identical: usize,
    /// Resident memory per keyframe with the f32 rows in a file.
    file_per_keyframe: Option<f64>,
}

/// This process's resident set size, from `/proc/self/status`.
fn resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// A table cell for resident bytes per keyframe, against the f32
/// descriptor's size.
fn per_keyframe_cell(bytes: Option<f64>, dim: usize) -> String {
    bytes.map_or("-".to_string(), |b| {
        format!("{b:.0} B ({:.2}x the f32 descriptor)", b / (4 * dim) as f64)
    })
}

/// The scoped case's store: `robots` robots of `keyframes` keyframes each,
/// inserted in turn as a fleet's arrive; each robot's first half of
/// keyframes is its map 0, the second half its map 1. The newest rows are
/// grouped by map as the store's writer groups them (every
/// [`humem_core::index::GROUP_TAIL_ROWS`] inserts), so the rows of the
/// last, ungrouped tail stay scattered as they would be in a server.
fn fleet_store(robots: usize, keyframes: usize, dim: usize) -> (Index, Vec<Duration>) {
    let rows = robots * keyframes;
    let mut index = Index::new(dim);
    let mut groupings = Vec::new();
    let mut fleet = SyntheticFleet::new(rows, dim, robots);
    for i in 0..rows {
        let mut keyframe = fleet.keyframe(i);
        keyframe.map_id = u64::from(keyframe.key.keyframe_id >= (keyframes / 2) as u64);
        index.upsert(keyframe);
        // As the store's writer does it: the plan while queries go on, the
        // placing (timed) with the index to itself.
        if index.ungrouped_rows() >= humem_core::index::GROUP_TAIL_ROWS {
            if let Some(plan) = index.plan_tail_grouping() {
                let (took, _) = timed(|| index.apply_grouping(plan));
                groupings.push(took);
            }
        }
    }
    (index, groupings)
}

/// The scoped case's queries: what a robot may see, narrowest first.
const SCOPES: [(&str, Scope, bool); 3] = [
    ("SAME_MAP", Scope::SameMap, false),
    ("ALL_MAPS, reads only its own robot", Scope::AllMaps, true),
    ("ALL_MAPS", Scope::AllMaps, false),
];

/// One scope's figures in the scoped case.
struct ScopedRow {
    name: &'static str,
    eligible: u64,
    full: f64,
    partitioned: f64,
    identical: usize,
}

/// Erases `share` of the rows of `index` (a [`fleet_store`] of `robots` x
/// `keyframes`) at random, never one of robot 0's `kept` keyframes, each
/// erasure followed by a new keyframe of the next robot in its map 1, and
/// groups the tail and sorts scattered windows again as the store's writer
/// does after each group of changes; returns how long each window's sorting
/// held the index (the placing half, as in fleet_store).
fn churn(
    index: &mut Index,
    robots: usize,
    keyframes: usize,
    share: f64,
    kept: &[u64],
) -> Vec<Duration> {
    let changes = (share * (robots * keyframes) as f64) as usize;
    let mut fleet = SyntheticFleet::new(robots * keyframes, index.dim(), robots);
    let mut rng = Rng::new(11);
    let mut next = robots * keyframes;
    let mut done = 0;
    let mut regroupings = Vec::new();
    while done < changes {
        let robot = rng.next() as usize % robots;
        let id = rng.next() % (next / robots) as u64;
        let key = KeyframeKey {
            robot_id: format!("robot-{robot}"),
            session_id: "session".into(),
            keyframe_id: id,
        };
        if (robot == 0 && kept.contains(&id)) || !index.remove(&key) {
            continue;
        }
        let mut keyframe = fleet.keyframe(next);
        keyframe.map_id = 1;
        index.upsert(keyframe);
        next += 1;
        done += 1;
        index.group_tail_if_due();
        if let Some(plan) = index.plan_window_regrouping() {
            let (took, _) = timed(|| index.apply_grouping(plan));
            regroupings.push(took);
        }
    }
    regroupings
}

/// How many runs of consecutive rows robot 0's map 1 forms, and its rows:
/// a scoped scan reads a run at memory speed and pays a fresh read for
/// every run it starts.
fn runs_of_queried_map(index: &Index) -> (usize, usize) {
    let of_queried_map = |row: usize| {
        let meta = index.meta(row);
        meta.map_id == 1 && meta.key.robot_id == "robot-0"
    };
    let rows = (0..index.len()).filter(|&r| of_queried_map(r));
    let runs = rows
        .clone()
        .filter(|&r| r == 0 || !of_queried_map(r - 1))
        .count();
    (runs, rows.count())
}

/// The scoped case: robot 0's loop queries (in its map 1) over each of
/// [`SCOPES`], on every core as the server runs them, with the partitioned
/// scan and with a scan of every row (what a query cost before the store
/// was partitioned), answers compared; then, with `--scoped-churn`, the
/// same after a share of the store was erased and replaced by new
/// keyframes.
fn scoped(config: &Config, args: &ScanBench) -> anyhow::Result<Vec<(String, Vec<ScopedRow>)>> {
    let (robots, keyframes) = (args.scoped_robots, args.scoped_keyframes);
    ensure!(keyframes >= 200, "--scoped-keyframes must be at least 200");
    ensure!(
        (0.0..1.0).contains(&args.scoped_churn),
        "--scoped-churn must be in [0, 1)"
    );
    eprintln!(
        "bench scan: building the scoped store, {robots} robots x {keyframes} keyframes x {}",
        args.dim
    );
    let (mut index, groupings) = fleet_store(robots, keyframes, args.dim);
    let max = groupings
        .iter()
        .max()
        .map_or(0.0, |d| d.as_secs_f64() * 1e3);
    eprintln!(
        "bench scan: the newest rows grouped by map {} times (every {} inserts), the index held for a median {:.1} ms, at most {max:.1} ms; {} rows not yet grouped at the end",
        groupings.len(),
        humem_core::index::GROUP_TAIL_ROWS,
        median_ms(&groupings),
        index.ungrouped_rows()
    );
    let mut rng = Rng::new(7);
    let half = (keyframes / 2) as u64;
    let ids: Vec<u64> = (0..args.queries + 2)
        .map(|_| half + 2 + rng.next() % (half - 2))
        .collect();
    let (runs, rows) = runs_of_queried_map(&index);
    let mut tables = vec![(
        format!("as inserted (the queried map: {rows} rows in {runs} runs)"),
        scoped_queries(config, &index, &ids)?,
    )];
    if args.scoped_churn > 0.0 {
        let regroupings = churn(&mut index, robots, keyframes, args.scoped_churn, &ids);
        eprintln!(
            "bench scan: windows of {} rows sorted again {} times during the churn, the index held for a median {:.1} ms, at most {:.1} ms",
            humem_core::index::GROUP_WINDOW_ROWS,
            regroupings.len(),
            median_ms(&regroupings),
            regroupings.iter().max().map_or(0.0, |d| d.as_secs_f64() * 1e3)
        );
        let (runs, rows) = runs_of_queried_map(&index);
        tables.push((
            format!(
                "after {:.0} % of the store was erased and replaced (the queried map: {rows} rows in {runs} runs)",
                100.0 * args.scoped_churn
            ),
            scoped_queries(config, &index, &ids)?,
        ));
        // The best any regrouping could do: every row sorted at once.
        let (sorted, _) = timed(|| index.sort_rows(0, index.len()));
        eprintln!(
            "bench scan: the whole store sorted at once for the next table, the index held for {:.0} ms",
            sorted.as_secs_f64() * 1e3
        );
        tables.push((
            "the same store with every row sorted at once (what a whole-store regrouping would reach)".into(),
            scoped_queries(config, &index, &ids)?,
        ));
    }
    Ok(tables)
}

/// [`SCOPES`]' figures for the queries of robot 0's keyframes `ids` (the
/// first two warm up and are not timed).
fn scoped_queries(config: &Config, index: &Index, ids: &[u64]) -> anyhow::Result<Vec<ScopedRow>> {
    let k = config.vpr.top_k;
    let mut table = Vec::new();
    for (name, scope, own_only) in SCOPES {
        let (mut full, mut parted, mut identical, mut eligible) = (vec![], vec![], 0, 0);
        for (n, &id) in ids.iter().enumerate() {
            let mut spec = spec(id, k);
            spec.scope = scope.clone();
            spec.map_id = Some(1);
            if own_only {
                spec.readable_robots = Some(vec!["robot-0".into()]);
            }
            let (t_full, a) = timed(|| query::run_full_scan(index, &config.vpr, &spec));
            let (t_parted, b) = timed(|| query::run(index, &config.vpr, &spec));
            let (a, b) = (
                a.map_err(|e| anyhow::anyhow!("query {id}: {e:?}"))?,
                b.map_err(|e| anyhow::anyhow!("query {id}: {e:?}"))?,
            );
            eligible = b.eligible;
            if n < 2 {
                continue;
            }
            full.push(t_full);
            parted.push(t_parted);
            if answer(&a) == answer(&b) && a.eligible == b.eligible {
                identical += 1;
            }
        }
        table.push(ScopedRow {
            name,
            eligible,
            full: median_ms(&full),
            partitioned: median_ms(&parted),
            identical,
        });
    }
    Ok(table)
}

/// Prints one of the scoped case's tables.
fn print_scoped(args: &ScanBench, state: &str, table: &[ScopedRow]) {
    let threads = rayon::current_num_threads();
    let store = args.scoped_robots * args.scoped_keyframes;
    let all = table.last().map_or(f64::NAN, |r| r.partitioned);
    println!();
    println!(
        "Scoped queries: {} robots x {} keyframes ({store}, {}-d, two maps a robot), {state}, robot 0's loop queries, SCAL only, {threads} cores, median of {}; ratios against ALL_MAPS in the same run",
        args.scoped_robots, args.scoped_keyframes, args.dim, args.queries
    );
    println!("| query | eligible | every row scanned | partitioned | partitioned vs ALL_MAPS | same answers |");
    println!("| --- | --- | --- | --- | --- | --- |");
    for r in table {
        println!(
            "| {} | {} ({:.1} %) | {:.1} ms | {:.1} ms ({:.2}x) | {:.3}x | {}/{} |",
            r.name,
            r.eligible,
            100.0 * r.eligible as f64 / store as f64,
            r.full,
            r.partitioned,
            r.partitioned / r.full,
            r.partitioned / all,
            r.identical,
            args.queries
        );
    }
}

/// The query configurations every store size is measured with: the exact
/// and the compressed pass, on one core (`one_core`) or on every core.
struct Passes {
    one_core: rayon::ThreadPool,
    exact: VprParams,
    compressed: VprParams,
    k: usize,
}

/// Times of the passes with the f32 rows in memory, the first two
/// (warm-up) queries left out.
struct MemoryPass {
    flat: Vec<Duration>,
    exact: Vec<Duration>,
    compressed_one: Vec<Duration>,
    compressed_all: Vec<Duration>,
    /// Queries whose compressed answers equal the exact pass's.
    identical: usize,
    /// The exact pass's answer to every query, warm-ups included.
    exact_answers: Vec<Vec<(KeyframeKey, f32)>>,
}

/// Times of the compressed pass with the f32 rows in a file.
struct FilePass {
    one: Vec<Duration>,
    all: Vec<Duration>,
    /// Queries whose answers equal the exact pass's (rows in memory).
    identical: usize,
}

impl Passes {
    /// Builds a store of `rows` keyframes and measures every pass on it.
    fn measure(&self, args: &ScanBench, rows: usize) -> anyhow::Result<Row> {
        eprintln!("bench scan: building a store of {rows} x {}", args.dim);
        let resident_before = resident_bytes();
        let started = Instant::now();
        let mut index = store(rows, args.dim, args.robots);
        let build = started.elapsed();
        let added_per_keyframe = || {
            resident_bytes()
                .zip(resident_before)
                .map(|(after, before)| after.saturating_sub(before) as f64 / rows as f64)
        };
        let per_keyframe = added_per_keyframe();
        let per_robot = (rows / args.robots) as u64;
        ensure!(per_robot > 2, "--rows too small for {} robots", args.robots);
        let mut rng = Rng::new(99);
        let ids: Vec<u64> = (0..args.queries + 2)
            .map(|_| 2 + rng.next() % (per_robot - 2))
            .collect();
        let memory = self.memory_pass(&index, &ids)?;

        // The same compressed queries with the f32 rows moved to a file,
        // as `store.descriptors = "auto"` does in the server.
        let dir = match &args.dir {
            Some(dir) => tempfile::tempdir_in(dir),
            None => tempfile::tempdir(),
        }
        .context("creating a directory for the row file")?;
        index
            .move_descriptors_to_file(dir.path())
            .context("moving the descriptors to a file")?;
        let file_per_keyframe = added_per_keyframe();
        let file = self.file_pass(&index, &ids, &memory.exact_answers)?;
        let row = Row {
            rows,
            build,
            flat: median_ms(&memory.flat),
            exact: median_ms(&memory.exact),
            compressed_one: median_ms(&memory.compressed_one),
            compressed_all: median_ms(&memory.compressed_all),
            identical: memory.identical,
            queries: args.queries,
            per_keyframe,
            file_one: median_ms(&file.one),
            file_all: median_ms(&file.all),
            file_identical: file.identical,
            file_per_keyframe,
        };
        drop(index);
        Ok(row)
    }

    /// The flat scan, the exact pass on one core and the compressed pass on
    /// one and on every core, for each query of `ids`; the first two queries
    /// warm caches and are not timed.
    fn memory_pass(&self, index: &Index, ids: &[u64]) -> anyhow::Result<MemoryPass> {
        let k = self.k;
        let mut pass = MemoryPass {
            flat: vec![],
            exact: vec![],
            compressed_one: vec![],
            compressed_all: vec![],
            identical: 0,
            exact_answers: Vec::new(),
        };
        for (n, &id) in ids.iter().enumerate() {
            let spec = spec(id, k);
            let key = spec.session.keyframe(id);
            let row = index.row_of(&key).context("query keyframe stored")?;
            let q = index.descriptor(row).to_vec();
            let (flat_time, top) = self.one_core.install(|| timed(|| flat_scan(index, &q, k)));
            std::hint::black_box(&top);
            let mut outcomes = Vec::new();
            for (pool_one, p) in [
                (true, &self.exact),
                (true, &self.compressed),
                (false, &self.compressed),
            ] {
                let run = || query::run(index, p, &spec);
                let (t, outcome) = if pool_one {
                    self.one_core.install(|| timed(run))
                } else {
                    timed(run)
                };
                let outcome = outcome.map_err(|e| anyhow::anyhow!("query {id}: {e:?}"))?;
                outcomes.push((t, answer(&outcome)));
            }
            pass.exact_answers.push(outcomes[0].1.clone());
            if n < 2 {
                continue;
            }
            pass.flat.push(flat_time);
            pass.exact.push(outcomes[0].0);
            pass.compressed_one.push(outcomes[1].0);
            pass.compressed_all.push(outcomes[2].0);
            if outcomes[1].1 == outcomes[0].1 && outcomes[2].1 == outcomes[0].1 {
                pass.identical += 1;
            }
        }
        Ok(pass)
    }

    /// The compressed pass on one and on every core, its answers checked
    /// against `exact_answers`; the first two queries are not timed.
    fn file_pass(
        &self,
        index: &Index,
        ids: &[u64],
        exact_answers: &[Vec<(KeyframeKey, f32)>],
    ) -> anyhow::Result<FilePass> {
        let mut pass = FilePass {
            one: vec![],
            all: vec![],
            identical: 0,
        };
        for (n, (&id, exact)) in ids.iter().zip(exact_answers).enumerate() {
            let spec = spec(id, self.k);
            let run = || query::run(index, &self.compressed, &spec);
            let (one, a) = self.one_core.install(|| timed(run));
            let (all, b) = timed(run);
            let (a, b) = (
                a.map_err(|e| anyhow::anyhow!("query {id}: {e:?}"))?,
                b.map_err(|e| anyhow::anyhow!("query {id}: {e:?}"))?,
            );
            if n < 2 {
                continue;
            }
            pass.one.push(one);
            pass.all.push(all);
            if &answer(&a) == exact && &answer(&b) == exact {
                pass.identical += 1;
            }
        }
        Ok(pass)
    }
}

/// Prints the tables of every store size: the rows in memory, then in a
/// file.
fn print_table(args: &ScanBench, table: &[Row], k: usize, threads: usize) {
    println!(
        "SCAL-only query, {}-d, top {k}, median of {} queries, code kernel {}; ratios against the exact f32 scan on 1 core",
        args.dim,
        args.queries,
        humem_core::engine::kernels::CodeKernel::detect().name()
    );
    println!(
        "| keyframes | exact f32 scan, 1 core | HuMem exact, 1 core | HuMem compressed, 1 core | HuMem compressed, {threads} cores | same answers as exact | resident per keyframe | store built in |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- |");
    for r in table {
        println!(
            "| {} | {:.1} ms | {:.1} ms ({:.2}x) | {:.1} ms ({:.2}x) | {:.1} ms ({:.2}x) | {}/{} | {} | {:.0} s |",
            r.rows,
            r.flat,
            r.exact,
            r.exact / r.flat,
            r.compressed_one,
            r.compressed_one / r.flat,
            r.compressed_all,
            r.compressed_all / r.flat,
            r.identical,
            r.queries,
            per_keyframe_cell(r.per_keyframe, args.dim),
            r.build.as_secs_f64()
        );
    }
    println!();
    println!("The compressed pass again, with the f32 rows moved to a file (store.descriptors = \"file\"; \"auto\" from 1 GiB of descriptors):");
    println!(
        "| keyframes | HuMem compressed, 1 core | HuMem compressed, {threads} cores | same answers as exact | resident per keyframe |"
    );
    println!("| --- | --- | --- | --- | --- |");
    for r in table {
        println!(
            "| {} | {:.1} ms ({:.2}x) | {:.1} ms ({:.2}x) | {}/{} | {} |",
            r.rows,
            r.file_one,
            r.file_one / r.flat,
            r.file_all,
            r.file_all / r.flat,
            r.file_identical,
            r.queries,
            per_keyframe_cell(r.file_per_keyframe, args.dim),
        );
    }
}

/// Runs the benchmark and prints the table.
pub fn scan(config: Config, args: ScanBench) -> anyhow::Result<()> {
    ensure!(args.queries > 0, "--queries must be at least 1");
    ensure!(args.robots > 0, "--robots must be at least 1");
    ensure!(args.dim > 0, "--dim must be at least 1");
    let threads = rayon::current_num_threads();
    let one_core = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .context("building a one-thread pool")?;
    let params = |scan| VprParams {
        scan,
        ..config.vpr.clone()
    };
    let passes = Passes {
        one_core,
        exact: params(ScanMode::Exact),
        compressed: params(ScanMode::Compressed),
        k: config.vpr.top_k,
    };
    let mut table = Vec::new();
    for &rows in &args.rows {
        table.push(passes.measure(&args, rows)?);
    }
    print_table(&args, &table, passes.k, threads);
    if args.scoped_robots > 0 {
        for (state, table) in scoped(&config, &args)? {
            print_scoped(&args, &state, &table);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flat_scan_finds_the_best_rows() {
        let index = store(2_000, 32, 4);
        let q = index.descriptor(10).to_vec();
        let top = flat_scan(&index, &q, 5);
        assert_eq!(top.len(), 5);
        let mut all: Vec<(f32, usize)> = (0..index.len())
            .map(|r| (dot_f32_wide(&q, &index.descriptor(r)), r))
            .collect();
        all.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut top_rows: Vec<usize> = top.iter().map(|t| t.1).collect();
        let mut best_rows: Vec<usize> = all[..5].iter().map(|t| t.1).collect();
        top_rows.sort();
        best_rows.sort();
        assert_eq!(top_rows, best_rows);
        assert!(
            top.iter().any(|&(_, r)| r == 10),
            "a row is its own best match"
        );
    }

    #[test]
    fn the_scoped_case_answers_as_the_full_scan_and_sees_what_its_scope_allows() {
        let args = ScanBench {
            rows: vec![],
            dim: 32,
            queries: 3,
            robots: 1,
            dir: None,
            scoped_robots: 10,
            scoped_keyframes: 400,
            scoped_churn: 0.3,
        };
        let tables = scoped(&Config::default(), &args).unwrap();
        assert_eq!(tables.len(), 3, "as inserted, after the churn, sorted");
        let churned = &tables[1].1;
        assert!(churned.iter().all(|r| r.identical == 3));
        assert!(tables[2].1.iter().all(|r| r.identical == 3));
        // The churn keeps the store's size, so every keyframe is still
        // eligible over ALL_MAPS.
        assert!(churned[2].eligible > 3_900, "{}", churned[2].eligible);
        let table = &tables[0].1;
        let eligible: Vec<u64> = table.iter().map(|r| r.eligible).collect();
        // One map of robot 0 less the gap window, both of its maps, then
        // every keyframe (other robots' rows are always eligible).
        assert!(eligible[0] < 200 && eligible[0] > 100, "{eligible:?}");
        assert!(eligible[1] < 400 && eligible[1] > 300, "{eligible:?}");
        assert!(eligible[2] > 3_900, "{eligible:?}");
        assert!(table.iter().all(|r| r.identical == 3));
    }

    #[test]
    fn the_compressed_query_answers_as_the_exact_one_on_a_clustered_store() {
        let index = store(40_000, 64, 8);
        for id in [100, 2_000, 4_000] {
            let spec = spec(id, 25);
            let run = |scan| {
                let params = VprParams {
                    scan,
                    ..VprParams::default()
                };
                answer(&query::run(&index, &params, &spec).unwrap())
            };
            let exact = run(ScanMode::Exact);
            assert_eq!(exact.len(), 25);
            assert_eq!(run(ScanMode::Compressed), exact, "query {id}");
        }
    }
}
