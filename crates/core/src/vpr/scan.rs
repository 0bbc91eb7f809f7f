//! The SCAL pass over the whole eligible store, on every core.
//!
//! SCAL is the only layer that reads every stored keyframe, so its pass is
//! what a query costs at fleet scale. Two passes return the same hits and
//! the same null model, bit for bit:
//!
//! - **exact**: every row's f32 descriptor against the query and its
//!   predecessors (one fused read), then `S_s` for every eligible row;
//! - **compressed**: the one-byte [`codes`](crate::engine::codes) first, a quarter
//!   of the bytes, giving for every row an upper bound on its `s_e`
//!   (estimate plus the code error bound). `S_s` is monotone in each `s_e`,
//!   so the same temporal formula over the upper bounds bounds `S_s` from
//!   above, first without the scene modulation (it only lowers a score),
//!   then with it for the rows still in the running. The `K` rows with the
//!   highest bounds are scored exactly; the lowest of those exact scores,
//!   `L`, is a lower bound on the K-th best exact score, so only rows whose
//!   bound reaches `L` can be in the top K, and only those are scored
//!   exactly. The null model's sample (every `stride`-th eligible row) is
//!   scored exactly too.
//!
//! [`ScanMode::Auto`] takes the compressed pass from
//! [`COMPRESSED_MIN_ROWS`] rows, where the sample and the rescoring are
//! small next to the rows it saves reading, on CPUs whose code kernel is
//! faster than the f32 scan ([`CodeKernel::pays_off`]: AVX-512 VNNI or AVX2).
//!
//! Both passes split the rows into blocks that rayon runs on every core;
//! each row's result depends only on the row, and ties order by row, so the
//! answer does not depend on the number of threads.
//!
//! A third pass is approximate, for queries that may see many keyframes
//! (a fleet's merge query over every other map): where the memory keeps a
//! neighbour graph and the eligible rows number `vpr.approximate_from` or
//! more (and neither `vpr.exact` nor the query asks for an exact pass),
//! the graph proposes the `approximate_candidates` eligible rows nearest
//! to the current observation, the scopes and access rules applied while
//! it is walked; the best `K` of them by their exact scores, temporal
//! context included, are kept (scoring exactly only the candidates whose
//! code bounds reach the K-th highest lower bound, as the compressed pass
//! does: the same best K from a fraction of the f32 rows). Its cost grows
//! with the logarithm of the store, not the store; what it can get wrong
//! is only a row the graph did not propose. Its null model is approximate
//! too, and cheap: a sample of 1–2 thousand eligible rows chosen by their
//! tags as the full passes' (the tag a multiple of a power of two, a mask
//! over the tags), each
//! scored from the codes' estimates alone; the eligible count is the rows
//! of the admitted maps. Bounding the sample and rescoring it exactly, as
//! the compressed pass does, cost four times the graph's search and
//! changed the calibration by less than the sample's own noise.
//!
//! A filter that names its [partition](RowFilter::partition) (the rows of
//! the maps a query may see) is scanned over those rows only, in row
//! order: the same blocks, read in runs of consecutive rows. Every row's
//! bounds and scores are computed as in the full pass, the null sample is
//! the same (it is drawn from the eligible rows by their tags), and the
//! answer is the full pass's, bit for bit; only its cost follows the
//! partition.

use std::cell::Cell;
use std::cmp::Ordering;

use rayon::prelude::*;

use crate::engine::codes::QueryCode;
use crate::engine::filter::{RowFilter, RowGroup};
use crate::engine::kernels::CodeKernel;
use crate::engine::visit::Visit;
use crate::vpr::calibration::{NullModel, Sampler};
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::params::{ScanMode, VprParams};
use crate::vpr::query_side::QuerySide;
use crate::vpr::scal::{temporal_hit, ScalHit, ScalQuery, STEPS};

/// Stored rows from which [`ScanMode::Auto`] scans the codes first.
pub const COMPRESSED_MIN_ROWS: usize = 32_768;

/// Rows per block of parallel work.
const BLOCK: usize = 4096;

/// The fewest rows per block of the exact pass over a small visit.
const MIN_BLOCK: usize = 256;

/// Rows per block of the exact pass over `rows` rows: [`BLOCK`], or fewer
/// when that would leave cores idle (a query's partition of a few
/// thousand rows), so that every core gets two blocks. Each row's result
/// depends only on the row, so the blocks change the time, not the answer.
fn exact_block(rows: usize) -> usize {
    rows.div_ceil(2 * rayon::current_num_threads())
        .clamp(MIN_BLOCK, BLOCK)
}

/// How many runs ahead a scan over scattered rows prefetches
/// ([`DescriptorMatrix::prefetch_row`](crate::engine::matrix::DescriptorMatrix::prefetch_row)).
const PREFETCH_RUNS_AHEAD: usize = 4;

/// What one SCAL pass found.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ScalScan {
    /// The top `K` hits by `S_s` descending (ties: lower row first).
    pub hits: Vec<ScalHit>,
    /// The query's null distribution over the eligible rows.
    pub null: NullModel,
    /// Rows that passed eligibility.
    pub eligible: usize,
}

/// SCAL over every eligible row: the top `params.top_k` hits by `S_s`
/// descending (ties: lower row first), without the null model. Empty if
/// the query has no history.
pub fn scal_scores<M, E>(
    params: &VprParams,
    query: &ScalQuery,
    memory: &M,
    eligible: &E,
) -> Vec<ScalHit>
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    scal_scan(params, query, memory, eligible).hits
}

/// SCAL over every eligible row (see the module doc for the two passes).
/// Empty if the query has no history.
pub fn scal_scan<M, E>(params: &VprParams, query: &ScalQuery, memory: &M, eligible: &E) -> ScalScan
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    if query.history.is_empty() {
        return ScalScan::default();
    }
    let side = QuerySide::new(params, &query.history);
    let matrix = memory.descriptors();
    if let Some(plan) = approximate_for(params, eligible, matrix.len()) {
        if let Some(scan) = approximate_scan(params, &side, memory, eligible, plan) {
            return scan;
        }
    }
    let visit = match eligible.partition() {
        Some(rows) => Visit::Only(rows),
        None => Visit::All(matrix.len()),
    };
    // In memory, the codes pay off from enough visited rows; in a file,
    // every f32 row read is a system call, so the store's size decides.
    let rows = if matrix.in_memory() {
        visit.len()
    } else {
        matrix.len()
    };
    if codes_first_from(params.scan).is_some_and(|from| rows >= from) {
        compressed_scan(params, &side, memory, eligible, visit)
    } else {
        exact_scan(params, &side, memory, eligible, visit)
    }
}

/// The planner's choice of the neighbour graph: how many rows are
/// eligible, and which graph proposes them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Approximate {
    /// The rows of the admitted maps.
    admitted: usize,
    /// The one admitted map's own graph; None: the store's graph, walked
    /// with the filter.
    group: Option<RowGroup>,
}

/// The planner: whether a query is answered from the neighbour graph's
/// candidates instead of a full pass. Only where its eligible rows are
/// enough for the graph to pay (`approximate_from`, not `exact`); then
/// from the store's graph where they are a large enough share of the
/// `stored` rows for its filtered walk to find them cheaply
/// (`approximate_min_share`), else from the graph of the one map they
/// belong to, where they are one map (a loop query over a robot's own
/// large map); None: a full pass.
fn approximate_for<E: RowFilter + ?Sized>(
    params: &VprParams,
    eligible: &E,
    stored: usize,
) -> Option<Approximate> {
    let admitted = eligible.admitted()?;
    if params.exact || admitted < params.approximate_from {
        return None;
    }
    let share_enough = admitted as f64 >= f64::from(params.approximate_min_share) * stored as f64;
    if share_enough {
        return Some(Approximate {
            admitted,
            group: None,
        });
    }
    eligible.group().map(|group| Approximate {
        admitted,
        group: Some(group),
    })
}

/// The approximate pass: the neighbour graph's `approximate_candidates`
/// eligible rows nearest to the current observation, the best `top_k` by
/// their exact scores (with temporal context) kept, only those whose code
/// bounds leave them a chance scored exactly; the null model from
/// the codes over a tag sample ([`approximate_sample`]), with `admitted`
/// standing for the eligible count. None where the memory keeps no such
/// graph (or it is not ready): the caller makes a full pass.
fn approximate_scan<M, E>(
    params: &VprParams,
    side: &QuerySide,
    memory: &M,
    eligible: &E,
    plan: Approximate,
) -> Option<ScalScan>
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    let Approximate { admitted, group } = plan;
    let count = params.approximate_candidates.max(params.top_k);
    let keep = |row: usize| eligible.test(row);
    let candidates = memory.nearest(side.descriptors[0], count, group, &keep)?;
    let kernel = CodeKernel::detect();
    let codes = side.codes(memory, kernel);
    let bounds = CodeBounds {
        side,
        codes: &codes,
        kernel,
    };
    let open = bounds.open_candidates(params, memory, &candidates);
    let mut hits = side.exact_hits(params, memory, &open);
    top_k(&mut hits, params.top_k);
    let sample = approximate_sample(memory, eligible, admitted);
    let location = estimated_median(params, side, memory, &codes, kernel, &sample);
    Some(ScalScan {
        hits,
        null: NullModel {
            location,
            samples: admitted,
        },
        eligible: admitted,
    })
}

/// The approximate pass's null sample: the eligible rows whose sample tag
/// is a multiple of the power of two at or above the full pass's stride
/// (between half and all of [`NULL_SAMPLE_CAP`](crate::vpr::calibration::NULL_SAMPLE_CAP)
/// rows). Chosen by key as the full pass's is, so replicas and restarts
/// take the same sample; a mask instead of a division, tested over the
/// whole tag table at once ([`KeyframeMemory::rows_tagged`]) where the
/// query admits most of the store, and eligibility only for the rows the
/// mask keeps.
fn approximate_sample<M, E>(memory: &M, eligible: &E, admitted: usize) -> Vec<usize>
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    let stride = NullModel::stride(admitted).next_power_of_two();
    let mask = u32::try_from(stride - 1).unwrap_or(u32::MAX);
    // The same rows either way (the partition only leaves out rows the
    // test refuses), perhaps in another order, which the median ignores.
    let mut rows = Vec::new();
    let tag = |row: usize| memory.sample_tag(row);
    let partitioned = eligible.for_each_tagged_in_partition(mask, &tag, &mut |row| {
        if eligible.test(row) {
            rows.push(row);
        }
    });
    if !partitioned {
        rows = memory.rows_tagged(mask);
        rows.retain(|&row| eligible.test(row));
    }
    rows
}

/// The median `S_s` of `rows` from the codes' estimates of their products
/// (temporal context included), without reading an f32 row: the
/// approximate pass's null. Its error is the codes' (a fraction of a
/// percent of a product), far below the spread of the null, so the
/// calibrated scores move by less than the sample's own noise.
fn estimated_median<M: KeyframeMemory + ?Sized>(
    params: &VprParams,
    side: &QuerySide,
    memory: &M,
    codes: &[QueryCode],
    kernel: CodeKernel,
    rows: &[usize],
) -> f32 {
    if rows.is_empty() {
        return 0.0;
    }
    let steps = side.steps();
    let mut scores: Vec<f32> = rows
        .iter()
        .map(|&row| {
            temporal_hit(params, memory, steps, row, |c, j| {
                (
                    side.pair_estimate(memory, codes, kernel, c, j),
                    side.scenes[j].compatibility(memory.scene(c)),
                )
            })
            .score
        })
        .collect();
    let m = scores.len() / 2;
    let (_, median, _) = scores.select_nth_unstable_by(m, f32::total_cmp);
    *median
}

/// The fewest stored rows from which `mode` scans the codes first on this
/// CPU (None: never). From there on a query reads few f32 rows, which is
/// what lets a large store keep them out of memory.
pub fn codes_first_from(mode: ScanMode) -> Option<usize> {
    match mode {
        ScanMode::Auto => CodeKernel::detect()
            .pays_off()
            .then_some(COMPRESSED_MIN_ROWS),
        ScanMode::Exact => None,
        ScanMode::Compressed => Some(0),
    }
}

/// Ranking order of SCAL hits: `S_s` descending, then lower row first.
pub(crate) fn by_score(a: &ScalHit, b: &ScalHit) -> Ordering {
    b.score.total_cmp(&a.score).then(a.row.cmp(&b.row))
}

/// Keeps the best `k` hits in ranking order: `O(N + k log k)`.
pub(super) fn top_k(hits: &mut Vec<ScalHit>, k: usize) {
    if k == 0 {
        hits.clear();
        return;
    }
    if hits.len() > k {
        hits.select_nth_unstable_by(k - 1, by_score);
        hits.truncate(k);
    }
    hits.sort_unstable_by(by_score);
}

/// The f32 pass: every visited row's `s_e`, then `S_s` of every eligible
/// row.
fn exact_scan<M, E>(
    params: &VprParams,
    side: &QuerySide,
    memory: &M,
    eligible: &E,
    visit: Visit,
) -> ScalScan
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    let matrix = memory.descriptors();
    let dim = matrix.dim();
    // Block by block, and within a block run by run, so that rows kept in
    // a file are read in one call a run.
    let mut s_e = vec![[0.0; STEPS]; visit.len()];
    let block_rows = exact_block(visit.len());
    s_e.par_chunks_mut(block_rows)
        .enumerate()
        .for_each(|(b, out)| {
            let block = visit.block(b * block_rows, out.len());
            let runs = block.runs();
            for (k, &(at, first, len)) in runs.iter().enumerate() {
                // Scattered rows: the row a few runs ahead starts loading now
                // (a long run the hardware prefetcher follows on its own).
                if let Some(&(_, ahead, _)) = runs.get(k + PREFETCH_RUNS_AHEAD) {
                    matrix.prefetch_row(ahead);
                }
                let data = matrix.rows(first, len);
                for (i, r) in data.chunks_exact(dim).enumerate() {
                    out[at + i] = side.exact_row(memory, first + i, r);
                }
            }
        });
    let all = visit.block(0, visit.len());
    // A chain row outside the visited rows (a filter whose partition
    // splits a track) is scored on its own: the same value, read again.
    let s_e_of = |c: usize, j: usize| match visit.position(c) {
        Some(i) => s_e[i][j],
        None => side.exact_row(memory, c, &matrix.row(c))[j],
    };
    let mut hits: Vec<ScalHit> = (0..visit.len())
        .into_par_iter()
        .with_min_len(block_rows)
        .map(|i| all.row(i))
        .filter(|&row| eligible.test(row))
        .map(|row| {
            temporal_hit(params, memory, side.steps(), row, |c, j| {
                (s_e_of(c, j), side.scenes[j].compatibility(memory.scene(c)))
            })
        })
        .collect();
    let null = NullModel::estimate(hits.iter().map(|h| (h.score, memory.sample_tag(h.row))));
    let eligible = hits.len();
    top_k(&mut hits, params.top_k);
    ScalScan {
        hits,
        null,
        eligible,
    }
}

/// The code pass with exact re-scoring (see the module doc).
fn compressed_scan<M, E>(
    params: &VprParams,
    side: &QuerySide,
    memory: &M,
    eligible: &E,
    visit: Visit,
) -> ScalScan
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    let kernel = CodeKernel::detect();
    let codes = side.codes(memory, kernel);
    let bounds = CodeBounds {
        side,
        codes: &codes,
        kernel,
    };
    let k = params.top_k;
    let upper = bounds.upper_rows(memory, &visit);
    let (loose, eligible_count, bests) = bounds.loose(params, memory, eligible, &visit, &upper);
    if eligible_count == 0 || k == 0 {
        return ScalScan {
            hits: Vec::new(),
            null: NullModel::default(),
            eligible: eligible_count,
        };
    }

    // L: the lowest exact score among the K rows with the highest bounds.
    let mut seeds: Vec<(f32, usize)> = bests.into_iter().flatten().collect();
    keep_highest(&mut seeds, k);
    let floor = if eligible_count <= k {
        f32::NEG_INFINITY
    } else {
        let rows: Vec<usize> = seeds.iter().map(|&(_, row)| row).collect();
        side.exact_hits(params, memory, &rows)
            .iter()
            .map(|hit| hit.score)
            .fold(f32::INFINITY, f32::min)
    };

    // Every row that can reach L, scored exactly.
    let open = bounds.reaching(params, memory, &visit, &loose, floor);
    let mut hits = side.exact_hits(params, memory, &open);
    top_k(&mut hits, k);

    let sample_rows = null_sample_rows(memory, &visit, &loose, eligible_count);
    let location = sample_median(params, side, memory, &codes, kernel, &sample_rows);
    ScalScan {
        hits,
        null: NullModel {
            location,
            samples: eligible_count,
        },
        eligible: eligible_count,
    }
}

/// The query's codes and the kernel that reads them: what the compressed
/// pass bounds the rows' scores with.
pub(super) struct CodeBounds<'a, 'q> {
    pub(super) side: &'a QuerySide<'q>,
    pub(super) codes: &'a [QueryCode],
    pub(super) kernel: CodeKernel,
}

impl CodeBounds<'_, '_> {
    /// Upper bounds on every visited row's `s_e` from the codes, block by
    /// block, in runs of consecutive rows.
    pub(super) fn upper_rows<M: KeyframeMemory + ?Sized>(
        &self,
        memory: &M,
        visit: &Visit,
    ) -> Vec<[f32; STEPS]> {
        let mut upper = vec![[0.0f32; STEPS]; visit.len()];
        upper
            .par_chunks_mut(BLOCK)
            .enumerate()
            .for_each_init(Vec::new, |bounds, (b, out)| {
                let block = visit.block(b * BLOCK, out.len());
                for (at, first, len) in block.runs() {
                    self.side.upper_rows(
                        memory,
                        self.codes,
                        self.kernel,
                        first,
                        bounds,
                        &mut out[at..at + len],
                    );
                }
            });
        upper
    }

    /// Lower and upper bounds on `row`'s `S_s` (temporal context and
    /// scene modulation included) from the codes alone.
    fn score_bounds<M: KeyframeMemory + ?Sized>(
        &self,
        params: &VprParams,
        memory: &M,
        row: usize,
    ) -> (f32, f32) {
        let side = self.side;
        // Both walks visit the same chain row at each step: its bounds
        // come from one code product, kept by step.
        let seen: [Cell<Option<(f32, f32)>>; STEPS] = Default::default();
        let bound = |c: usize, j: usize, upper: bool| {
            let (lo, hi) = seen[j].get().unwrap_or_else(|| {
                let pair = side.pair_bounds(memory, self.codes, self.kernel, c, j);
                seen[j].set(Some(pair));
                pair
            });
            let compat = side.scenes[j].compatibility(memory.scene(c));
            (if upper { hi } else { lo }, compat)
        };
        let steps = side.steps();
        let lo = temporal_hit(params, memory, steps, row, |c, j| bound(c, j, false));
        let hi = temporal_hit(params, memory, steps, row, |c, j| bound(c, j, true));
        (lo.score, hi.score)
    }

    /// The neighbour graph's candidates that can be among the best `K`:
    /// with every candidate's score bounded from the codes, the K-th
    /// highest lower bound is a floor that each of the best K reaches (K
    /// candidates score at least their lower bounds), so only candidates
    /// whose upper bound reaches it are kept. Scoring those exactly gives
    /// the same best K as scoring every candidate, bit for bit, and reads
    /// a fraction of the f32 rows (each a system call where the rows are
    /// in a file).
    fn open_candidates<M: KeyframeMemory + ?Sized>(
        &self,
        params: &VprParams,
        memory: &M,
        candidates: &[usize],
    ) -> Vec<usize> {
        let k = params.top_k;
        if candidates.len() <= k || k == 0 {
            return candidates.to_vec();
        }
        let bounds: Vec<(f32, f32)> = candidates
            .iter()
            .map(|&row| self.score_bounds(params, memory, row))
            .collect();
        let mut lows: Vec<f32> = bounds.iter().map(|b| b.0).collect();
        let (_, &mut floor, _) = lows.select_nth_unstable_by(k - 1, |a, b| b.total_cmp(a));
        candidates
            .iter()
            .zip(&bounds)
            .filter(|(_, &(_, hi))| hi >= floor)
            .map(|(&row, _)| row)
            .collect()
    }

    /// Per block, a bound on `S_s` without the scene modulation (which
    /// only lowers it), reading a chain row's bounds wherever in the visit
    /// it is: after erasures and replacements a track's rows are scattered
    /// over the store, and bounding each such chain row on its own tripled
    /// the pass (`humem bench scan`, the scoped case after churn). Only
    /// chain rows outside the visit get their bound on their own.
    ///
    /// Returns the bounds (NaN marks an ineligible row), the number of
    /// eligible rows, and each block's K highest bounds with their rows.
    #[allow(clippy::type_complexity)]
    pub(super) fn loose<M, E>(
        &self,
        params: &VprParams,
        memory: &M,
        eligible: &E,
        visit: &Visit,
        upper: &[[f32; STEPS]],
    ) -> (Vec<f32>, usize, Vec<Vec<(f32, usize)>>)
    where
        M: KeyframeMemory + ?Sized,
        E: RowFilter + ?Sized,
    {
        let k = params.top_k;
        let steps = self.side.steps();
        let mut loose = vec![f32::NAN; visit.len()];
        let per_block: Vec<(usize, Vec<(f32, usize)>)> = loose
            .par_chunks_mut(BLOCK)
            .enumerate()
            .map(|(b, out)| {
                let block = visit.block(b * BLOCK, out.len());
                let upper_at = |c: usize, j: usize| match visit.position(c) {
                    Some(i) => upper[i][j],
                    None => {
                        self.side
                            .pair_bounds(memory, self.codes, self.kernel, c, j)
                            .1
                    }
                };
                // The block's K highest: candidates gather in a buffer of 4K,
                // cut back to the K highest whenever it fills; from then on a
                // row below the K-th highest so far cannot be among them.
                let capacity = 4 * k.max(1);
                let mut best = Vec::with_capacity(capacity);
                let (mut count, mut threshold) = (0, f32::NEG_INFINITY);
                for (i, slot) in out.iter_mut().enumerate() {
                    let row = block.row(i);
                    if eligible.test(row) {
                        let u =
                            temporal_hit(params, memory, steps, row, |c, j| (upper_at(c, j), None));
                        *slot = u.score;
                        count += 1;
                        if u.score >= threshold {
                            best.push((u.score, row));
                            if best.len() == capacity {
                                keep_highest(&mut best, k);
                                threshold = best.iter().fold(f32::INFINITY, |m, p| m.min(p.0));
                            }
                        }
                    }
                }
                keep_highest(&mut best, k);
                (count, best)
            })
            .collect();
        let (counts, bests): (Vec<usize>, Vec<Vec<(f32, usize)>>) = per_block.into_iter().unzip();
        (loose, counts.iter().sum(), bests)
    }

    /// The rows whose bound with the scene modulation still reaches
    /// `floor`: the only ones that can be in the top K. Plain loops over
    /// blocks of the bounds: a rayon item per row would cost more than the
    /// comparison.
    pub(super) fn reaching<M: KeyframeMemory + ?Sized>(
        &self,
        params: &VprParams,
        memory: &M,
        visit: &Visit,
        loose: &[f32],
        floor: f32,
    ) -> Vec<usize> {
        let side = self.side;
        let steps = side.steps();
        loose
            .par_chunks(BLOCK)
            .enumerate()
            .flat_map_iter(|(b, bounds)| {
                let block = visit.block(b * BLOCK, bounds.len());
                let mut found = Vec::new();
                for (i, &u) in bounds.iter().enumerate() {
                    if u >= floor {
                        let row = block.row(i);
                        let tight = temporal_hit(params, memory, steps, row, |c, j| {
                            (
                                side.pair_bounds(memory, self.codes, self.kernel, c, j).1,
                                side.scenes[j].compatibility(memory.scene(c)),
                            )
                        });
                        if tight.score >= floor {
                            found.push(row);
                        }
                    }
                }
                found
            })
            .collect()
    }
}

/// The null model's sample: the eligible rows (a bound that is not NaN)
/// whose key's tag the stride keeps, the same rows whatever their order.
fn null_sample_rows<M: KeyframeMemory + ?Sized>(
    memory: &M,
    visit: &Visit,
    loose: &[f32],
    eligible_count: usize,
) -> Vec<usize> {
    let sampler = Sampler::new(NullModel::stride(eligible_count));
    loose
        .par_chunks(BLOCK)
        .enumerate()
        .flat_map_iter(|(b, bounds)| {
            let block = visit.block(b * BLOCK, bounds.len());
            bounds
                .iter()
                .enumerate()
                .map(|(i, u)| (block.row(i), u))
                .filter(|&(row, u)| !u.is_nan() && sampler.keeps(memory.sample_tag(row)))
                .map(|(row, _)| row)
                .collect::<Vec<_>>()
        })
        .collect()
}

/// The median exact `S_s` of the sampled rows, as [`NullModel`] takes it
/// (the `len/2`-th smallest), scoring exactly only the rows whose bounds
/// leave it open which side of the median they are on.
///
/// With `lo_i ≤ S_i ≤ hi_i` and `m = len/2`, the median `v` lies in
/// `[lo_(m), hi_(m)]` (the m-th smallest bounds). A row with
/// `hi_i < lo_(m)` is below `v` and one with `lo_i > hi_(m)` above it, so
/// `v` is the `(m − #below)`-th smallest exact score of the rest.
pub(super) fn sample_median<M: KeyframeMemory + ?Sized>(
    params: &VprParams,
    side: &QuerySide,
    memory: &M,
    codes: &[QueryCode],
    kernel: CodeKernel,
    rows: &[usize],
) -> f32 {
    if rows.is_empty() {
        return 0.0;
    }
    let code_bounds = CodeBounds {
        side,
        codes,
        kernel,
    };
    let bounds: Vec<(f32, f32)> = rows
        .par_iter()
        .map(|&row| code_bounds.score_bounds(params, memory, row))
        .collect();
    let m = rows.len() / 2;
    let nth = |mut v: Vec<f32>| {
        let (_, x, _) = v.select_nth_unstable_by(m, f32::total_cmp);
        *x
    };
    let lo_m = nth(bounds.iter().map(|b| b.0).collect());
    let hi_m = nth(bounds.iter().map(|b| b.1).collect());
    let below = bounds.iter().filter(|b| b.1 < lo_m).count();
    let open_rows: Vec<usize> = rows
        .iter()
        .zip(&bounds)
        .filter(|(_, b)| b.1 >= lo_m && b.0 <= hi_m)
        .map(|(&row, _)| row)
        .collect();
    let mut open: Vec<f32> = side
        .exact_hits(params, memory, &open_rows)
        .iter()
        .map(|hit| hit.score)
        .collect();
    let (_, median, _) = open.select_nth_unstable_by(m - below, f32::total_cmp);
    *median
}

/// Keeps the `k` highest `(score, row)` pairs (ties: lower row), unordered.
pub(super) fn keep_highest(pairs: &mut Vec<(f32, usize)>, k: usize) {
    if pairs.len() > k && k > 0 {
        pairs.select_nth_unstable_by(k - 1, |a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    }
    pairs.truncate(k);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::keyframe::Features;
    use crate::keyframe::SceneClass;
    use crate::vpr::memory::VecMemory;
    use crate::vpr::params::TemporalMode;
    use crate::vpr::query_side::clip01_branchless;
    use crate::vpr::testing::{features_of, memory_strategy, scene_strategy, unit_vector};
    use proptest::prelude::*;

    /// Admits `admitted` rows (the rows of the maps a query may see), all
    /// of one map where a group is named.
    struct Admitting(usize, Option<RowGroup>);

    impl RowFilter for Admitting {
        fn test(&self, _row: usize) -> bool {
            true
        }

        fn admitted(&self) -> Option<usize> {
            Some(self.0)
        }

        fn group(&self) -> Option<RowGroup> {
            self.1
        }
    }

    #[test]
    fn the_planner_walks_the_store_graph_for_a_large_share_and_a_map_graph_for_one_large_map() {
        let params = VprParams::default();
        let from = params.approximate_from;
        let stored = 1_000_000;
        let plan = |params: &VprParams, admitted: usize, group: Option<RowGroup>| {
            approximate_for(params, &Admitting(admitted, group), stored)
                .map(|plan| (plan.admitted, plan.group))
        };
        // A merge query over most of the store: the store's graph, even
        // where it happens to name one map.
        assert_eq!(plan(&params, 950_000, None), Some((950_000, None)));
        assert_eq!(plan(&params, 950_000, Some(7)), Some((950_000, None)));
        // A loop query over one robot's map of 31 000 (3 %): that map's
        // graph; several robots' maps of as many: a pass.
        assert_eq!(plan(&params, 31_000, Some(7)), Some((31_000, Some(7))));
        assert_eq!(plan(&params, 31_000, None), None);
        // A sixteenth of the store is enough for the store's graph.
        assert_eq!(plan(&params, 62_500, None), Some((62_500, None)));
        // Fewer than `approximate_from`: a pass, whatever the map.
        assert_eq!(plan(&params, from - 1, Some(7)), None);
        assert_eq!(
            approximate_for(&params, &Admitting(from, None), from).map(|p| p.admitted),
            Some(from)
        );
        // The share rule off; exact on.
        let any_share = VprParams {
            approximate_min_share: 0.0,
            ..params.clone()
        };
        assert_eq!(plan(&any_share, 31_000, None), Some((31_000, None)));
        let exact = VprParams {
            exact: true,
            ..params
        };
        assert_eq!(plan(&exact, 950_000, None), None);
        assert_eq!(plan(&exact, 31_000, Some(7)), None);
    }

    fn run(
        params: &VprParams,
        mode: ScanMode,
        history: &[Features],
        m: &VecMemory,
        mask: &[bool],
    ) -> ScalScan {
        let params = VprParams {
            scan: mode,
            ..params.clone()
        };
        let query = ScalQuery {
            history: history.iter().collect(),
        };
        scal_scan(&params, &query, m, &|row| mask[row % mask.len()])
    }

    /// Descriptors in a few tight clusters, so that many rows score close to
    /// each other and to the query (the hard case for the bounds).
    fn clustered(n: usize, dim: usize, seed: u64) -> VecMemory {
        clustered_with(n, dim, seed, |i| (i % 7 != 0).then(|| i - 1))
    }

    /// [`clustered`] with each row's predecessor given by `predecessor`.
    fn clustered_with(
        n: usize,
        dim: usize,
        seed: u64,
        predecessor: impl Fn(usize) -> Option<usize>,
    ) -> VecMemory {
        let mut s = seed | 1;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        let centres: Vec<Vec<f32>> = (0..8).map(|_| (0..dim).map(|_| next()).collect()).collect();
        let mut m = VecMemory::new(dim);
        for i in 0..n {
            let c = &centres[i % centres.len()];
            let v: Vec<f32> = c.iter().map(|x| x + 0.05 * next()).collect();
            let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            let scene = vec![SceneClass {
                class_id: (i % 5) as u32,
                probability: 0.5 + next(),
            }];
            m.push(
                Features {
                    descriptor: v.iter().map(|x| x / norm).collect(),
                    scene,
                    ..Features::default()
                },
                predecessor(i),
            );
        }
        m
    }

    #[test]
    fn compressed_equals_exact_past_the_null_sample_cap() {
        let m = clustered(20_000, 48, 3);
        let history: Vec<Features> = [5, 4, 3].iter().map(|&r| m.features(r).clone()).collect();
        let mask: Vec<bool> = (0..13).map(|i| i != 4).collect();
        for temporal in [TemporalMode::Support, TemporalMode::Average] {
            for top_k in [1, 25, 300] {
                let params = VprParams {
                    temporal,
                    top_k,
                    ..VprParams::default()
                };
                let exact = run(&params, ScanMode::Exact, &history, &m, &mask);
                let compressed = run(&params, ScanMode::Compressed, &history, &m, &mask);
                assert!(exact.eligible > 16_384 && exact.hits.len() == top_k);
                assert_eq!(compressed, exact, "{temporal:?}, K = {top_k}");
            }
        }
        let auto = run(
            &VprParams::default(),
            ScanMode::Auto,
            &history[..1],
            &m,
            &mask,
        );
        assert_eq!(
            auto,
            run(
                &VprParams::default(),
                ScanMode::Exact,
                &history[..1],
                &m,
                &mask
            )
        );
    }

    #[test]
    fn the_branchless_clip_is_clip01_bit_for_bit() {
        let edges = [
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            0.0,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            1e-45,
            0.5,
            1.0,
            1.0 + f32::EPSILON,
            -1.0,
            3.0e38,
        ];
        for x in edges
            .into_iter()
            .chain((0..10_000).map(|i| (i as f32 - 5_000.0) * 3.1e-4))
        {
            assert_eq!(
                clip01_branchless(x).to_bits(),
                crate::numeric::clip01(x).to_bits(),
                "{x}"
            );
        }
    }

    #[test]
    fn the_answer_does_not_depend_on_the_number_of_threads() {
        let m = clustered(9_000, 32, 9);
        let history: Vec<Features> = [10, 9].iter().map(|&r| m.features(r).clone()).collect();
        let params = VprParams::default();
        let single = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        for mode in [ScanMode::Exact, ScanMode::Compressed] {
            let one = single.install(|| run(&params, mode, &history, &m, &[true]));
            assert_eq!(one, run(&params, mode, &history, &m, &[true]), "{mode:?}");
        }
    }

    #[test]
    fn rows_in_a_file_give_the_same_answers() {
        let mut m = clustered(9_000, 32, 5);
        let history: Vec<Features> = [20, 19, 18]
            .iter()
            .map(|&r| m.features(r).clone())
            .collect();
        let params = VprParams::default();
        let mask = [true, true, false];
        let exact = run(&params, ScanMode::Exact, &history, &m, &mask);
        let dir = tempfile::tempdir().unwrap();
        m.move_descriptors_to_file(dir.path()).unwrap();
        assert!(!m.descriptors().in_memory());
        for mode in [ScanMode::Exact, ScanMode::Compressed] {
            assert_eq!(run(&params, mode, &history, &m, &mask), exact, "{mode:?}");
        }
    }

    /// A filter that names a partition: `rows` must hold every row `test`
    /// admits.
    struct Parted<'a> {
        rows: Vec<usize>,
        test: &'a (dyn Fn(usize) -> bool + Sync),
    }

    impl RowFilter for Parted<'_> {
        fn test(&self, row: usize) -> bool {
            (self.test)(row)
        }
        fn partition(&self) -> Option<&[usize]> {
            Some(&self.rows)
        }
    }

    /// The two scans agree bit for bit: the same rows, scores, depths and
    /// null model.
    fn assert_same_bits(a: &ScalScan, b: &ScalScan) {
        assert_eq!(a.eligible, b.eligible);
        assert_eq!(a.null.samples, b.null.samples);
        assert_eq!(a.null.location.to_bits(), b.null.location.to_bits());
        assert_eq!(a.hits.len(), b.hits.len());
        for (x, y) in a.hits.iter().zip(&b.hits) {
            assert_eq!((x.row, x.depth), (y.row, y.depth));
            assert_eq!(x.score.to_bits(), y.score.to_bits(), "row {}", x.row);
            assert_eq!(x.cosine.to_bits(), y.cosine.to_bits());
            assert_eq!(
                x.scene_compatibility.map(f32::to_bits),
                y.scene_compatibility.map(f32::to_bits)
            );
        }
    }

    /// A partitioned scan against the full one, in both passes.
    fn check_partition(m: &VecMemory, history: &[Features], params: &VprParams, rows: Vec<usize>) {
        let member: Vec<bool> = (0..m.descriptors().len())
            .map(|r| rows.binary_search(&r).is_ok())
            .collect();
        let test = |row: usize| member[row] && row % 5 != 2;
        let parted = Parted { rows, test: &test };
        let query = ScalQuery {
            history: history.iter().collect(),
        };
        for mode in [ScanMode::Exact, ScanMode::Compressed] {
            let params = VprParams {
                scan: mode,
                ..params.clone()
            };
            let full = scal_scan(&params, &query, m, &test);
            assert_same_bits(&scal_scan(&params, &query, m, &parted), &full);
        }
    }

    #[test]
    fn a_partition_gives_the_full_scans_answer() {
        // Tracks are runs of 7 rows; "maps" of whole tracks, over several
        // blocks, and a partition that cuts tracks (chain rows outside it).
        let m = clustered(20_000, 48, 3);
        let history: Vec<Features> = [5, 4, 3].iter().map(|&r| m.features(r).clone()).collect();
        let maps: Vec<usize> = (0..20_000)
            .filter(|i| (i / 7) % 5 == 1 || (i / 7) % 5 == 3)
            .collect();
        let cut: Vec<usize> = (0..20_000).filter(|i| i % 3 != 0).collect();
        for top_k in [1, 25, 300] {
            let params = VprParams {
                top_k,
                ..VprParams::default()
            };
            check_partition(&m, &history, &params, maps.clone());
            check_partition(&m, &history, &params, cut.clone());
            check_partition(&m, &history, &params, vec![]);
        }
        // In a file, a partition is read in runs of consecutive rows.
        let mut m = m;
        let dir = tempfile::tempdir().unwrap();
        m.move_descriptors_to_file(dir.path()).unwrap();
        check_partition(&m, &history, &VprParams::default(), maps);
    }

    #[test]
    fn chains_scattered_over_blocks_give_the_same_answers() {
        // As in a store after many erasures: each row's predecessor lies up
        // to 9 000 rows back, mostly in another block of the passes, and a
        // partition that cuts the chains leaves some outside the visit.
        let m = clustered_with(20_000, 48, 5, |i| {
            (i % 7 != 0 && i > 0).then(|| i - 1 - (i * 7919) % i.min(9_000))
        });
        let history: Vec<Features> = [9_005, 17, 3]
            .iter()
            .map(|&r| m.features(r).clone())
            .collect();
        let mask = [true, true, false, true];
        for top_k in [1, 25, 300] {
            let params = VprParams {
                top_k,
                ..VprParams::default()
            };
            let exact = run(&params, ScanMode::Exact, &history, &m, &mask);
            assert_same_bits(
                &run(&params, ScanMode::Compressed, &history, &m, &mask),
                &exact,
            );
            let cut: Vec<usize> = (0..20_000).filter(|i| i % 3 != 0).collect();
            check_partition(&m, &history, &params, cut);
        }
    }

    /// The best `k` of `candidates` scored exactly: every candidate, and
    /// only those [`CodeBounds::open_candidates`] keeps (how many it kept).
    fn best_of_candidates(
        params: &VprParams,
        history: &[Features],
        m: &VecMemory,
        candidates: &[usize],
    ) -> (Vec<ScalHit>, Vec<ScalHit>, usize) {
        let history: Vec<&Features> = history.iter().collect();
        let side = QuerySide::new(params, &history);
        let kernel = CodeKernel::detect();
        let codes = side.codes(m, kernel);
        let bounds = CodeBounds {
            side: &side,
            codes: &codes,
            kernel,
        };
        let mut every = side.exact_hits(params, m, candidates);
        top_k(&mut every, params.top_k);
        let open = bounds.open_candidates(params, m, candidates);
        let mut kept = side.exact_hits(params, m, &open);
        top_k(&mut kept, params.top_k);
        (every, kept, open.len())
    }

    #[test]
    fn the_candidates_bounds_score_few_and_keep_the_best_k() {
        // Tight clusters, as a graph's candidates around a revisited place.
        let m = clustered(2_000, 64, 11);
        let params = VprParams::default();
        let history: Vec<Features> = [5, 4, 3]
            .iter()
            .map(|&row| Features {
                descriptor: m.descriptors().row(row).to_vec(),
                ..Features::default()
            })
            .collect();
        // Candidates from every cluster, a few dozen from the query's.
        let candidates: Vec<usize> = (0..2_000).step_by(7).take(256).collect();
        let (every, kept, scored) = best_of_candidates(&params, &history, &m, &candidates);
        assert_eq!(kept, every);
        assert_eq!(kept.len(), params.top_k);
        assert!(
            scored < candidates.len() / 2,
            "{scored} of 256 scored exactly"
        );
    }

    /// The defaults with `top_k` = `k`, averaging the temporal context or
    /// taking its support.
    fn params_of(k: usize, average: bool) -> VprParams {
        VprParams {
            top_k: k,
            temporal: if average {
                TemporalMode::Average
            } else {
                TemporalMode::Support
            },
            ..VprParams::default()
        }
    }

    proptest! {
        #[test]
        fn a_partition_never_changes_the_answer(
            m in memory_strategy(6, 80),
            history in prop::collection::vec((unit_vector(6), scene_strategy()), 1..4),
            member in prop::collection::vec(any::<bool>(), 80),
            k in 1usize..30,
        ) {
            let history = features_of(history);
            let params = VprParams { top_k: k, ..VprParams::default() };
            let rows = (0..m.descriptors().len()).filter(|&r| member[r]).collect();
            check_partition(&m, &history, &params, rows);
        }

        #[test]
        fn the_candidates_bounds_never_change_the_best_k(
            m in memory_strategy(6, 80),
            history in prop::collection::vec((unit_vector(6), scene_strategy()), 1..4),
            member in prop::collection::vec(any::<bool>(), 80),
            k in 1usize..30,
            average in any::<bool>(),
        ) {
            let history = features_of(history);
            let params = params_of(k, average);
            let candidates: Vec<usize> = (0..m.descriptors().len()).filter(|&r| member[r]).collect();
            let (every, kept, _) = best_of_candidates(&params, &history, &m, &candidates);
            prop_assert_eq!(kept, every);
        }

        #[test]
        fn compressed_equals_exact(
            m in memory_strategy(6, 80),
            history in prop::collection::vec((unit_vector(6), scene_strategy()), 1..4),
            mask in prop::collection::vec(any::<bool>(), 1..9),
            k in 1usize..30,
            average in any::<bool>(),
        ) {
            let history = features_of(history);
            let params = params_of(k, average);
            let exact = run(&params, ScanMode::Exact, &history, &m, &mask);
            prop_assert_eq!(run(&params, ScanMode::Compressed, &history, &m, &mask), exact);
        }
    }
}
