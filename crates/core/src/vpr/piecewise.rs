//! The compressed SCAL pass over a large store, in pieces of rows, so that
//! whoever holds the store's lock can let it go between them.
//!
//! An exact pass over a fleet's store reads every row and takes a few
//! hundred milliseconds. Held under the index's read lock in one go, it
//! keeps the store writer waiting that long, and every query that starts
//! meanwhile waits behind the writer: one exact pass stalled a whole
//! server. Cut into pieces, each piece is the compressed pass of
//! [`scan`](crate::vpr::scan) over its own rows, and what carries from
//! piece to piece is small:
//!
//! - **the best `K` so far**, exactly scored. The `K`-th of them is a lower
//!   bound on the `K`-th best exact score of the whole store, as the
//!   one-piece pass's floor is, so a later piece scores exactly only the
//!   rows whose code bound reaches it (or the piece's own floor, from its
//!   `K` highest bounds, where that is higher). Every row of the final
//!   best `K` reaches every floor, so it is scored; the best `K` of what
//!   was scored are the one-piece pass's, bit for bit.
//! - **the eligible rows**, in row order: the null sample's stride depends
//!   on their number, known only at the end; the sample is then the rows
//!   the stride keeps by their tags, the one-piece pass's rows in its
//!   order, and its median is taken as there.
//!
//! Row numbers carry from piece to piece, so they must keep naming the
//! same keyframes: the caller checks [`Index::renumberings`](crate::index::Index::renumberings)
//! between pieces and starts over when a removal or grouping renumbered
//! rows. Rows appended meanwhile are scanned as a last piece.

use crate::engine::codes::QueryCode;
use crate::engine::filter::RowFilter;
use crate::engine::kernels::CodeKernel;
use crate::engine::visit::Visit;
use crate::vpr::calibration::{NullModel, Sampler};
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::params::VprParams;
use crate::vpr::query_side::QuerySide;
use crate::vpr::scal::{ScalHit, ScalQuery};
use crate::vpr::scan::{keep_highest, sample_median, top_k, CodeBounds, ScalScan};

/// A compressed pass under way: what the pieces scanned so far found.
pub(crate) struct PiecewiseScan<'q> {
    side: QuerySide<'q>,
    kernel: CodeKernel,
    /// The best `K` hits so far, in ranking order.
    best: Vec<ScalHit>,
    /// Every eligible row scanned so far, ascending.
    eligible: Vec<usize>,
}

impl<'q> PiecewiseScan<'q> {
    /// A pass for `query`; None when it has no history (the pass finds
    /// nothing).
    pub(crate) fn new(params: &VprParams, query: &ScalQuery<'q>) -> Option<Self> {
        if query.history.is_empty() {
            return None;
        }
        Some(PiecewiseScan {
            side: QuerySide::new(params, &query.history),
            kernel: CodeKernel::detect(),
            best: Vec::new(),
            eligible: Vec::new(),
        })
    }

    /// Scans the rows of `visit` (after those of every earlier piece).
    pub(crate) fn scan<M, E>(&mut self, params: &VprParams, memory: &M, eligible: &E, visit: Visit)
    where
        M: KeyframeMemory + ?Sized,
        E: RowFilter + ?Sized,
    {
        let k = params.top_k;
        let codes = self.codes(memory);
        let bounds = CodeBounds {
            side: &self.side,
            codes: &codes,
            kernel: self.kernel,
        };
        let upper = bounds.upper_rows(memory, &visit);
        let (loose, count, bests) = bounds.loose(params, memory, eligible, &visit, &upper);
        let rows = visit.block(0, visit.len());
        self.eligible.extend(
            loose
                .iter()
                .enumerate()
                .filter(|(_, u)| !u.is_nan())
                .map(|(i, _)| rows.row(i)),
        );
        if count == 0 || k == 0 {
            return;
        }
        // The piece's K highest bounds that can still beat the best so
        // far, scored exactly: they raise the floor before the piece's
        // rows are tested against it.
        let best_so_far = floor(&self.best, k);
        let mut seeds: Vec<(f32, usize)> = bests
            .into_iter()
            .flatten()
            .filter(|&(bound, _)| bound >= best_so_far)
            .collect();
        keep_highest(&mut seeds, k);
        let mut seeds: Vec<usize> = seeds.into_iter().map(|(_, row)| row).collect();
        seeds.sort_unstable();
        let seeded = self.side.exact_hits(params, memory, &seeds);
        keep_best(&mut self.best, seeded, k);
        let open: Vec<usize> = bounds
            .reaching(params, memory, &visit, &loose, floor(&self.best, k))
            .into_iter()
            .filter(|row| seeds.binary_search(row).is_err())
            .collect();
        let opened = self.side.exact_hits(params, memory, &open);
        keep_best(&mut self.best, opened, k);
    }

    /// The pass's hits and null model, once every piece is scanned.
    pub(crate) fn finish<M: KeyframeMemory + ?Sized>(
        self,
        params: &VprParams,
        memory: &M,
    ) -> ScalScan {
        let count = self.eligible.len();
        if count == 0 || params.top_k == 0 {
            return ScalScan {
                hits: Vec::new(),
                null: NullModel::default(),
                eligible: count,
            };
        }
        let sampler = Sampler::new(NullModel::stride(count));
        let sample: Vec<usize> = self
            .eligible
            .iter()
            .copied()
            .filter(|&row| sampler.keeps(memory.sample_tag(row)))
            .collect();
        let codes = self.codes(memory);
        let location = sample_median(params, &self.side, memory, &codes, self.kernel, &sample);
        ScalScan {
            hits: self.best,
            null: NullModel {
                location,
                samples: count,
            },
            eligible: count,
        }
    }

    fn codes<M: KeyframeMemory + ?Sized>(&self, memory: &M) -> Vec<QueryCode> {
        self.side.codes(memory, self.kernel)
    }
}

/// The `K`-th best exact score so far: a lower bound on the whole pass's
/// `K`-th best (none before `K` rows were scored).
fn floor(best: &[ScalHit], k: usize) -> f32 {
    if k > 0 && best.len() >= k {
        best[k - 1].score
    } else {
        f32::NEG_INFINITY
    }
}

/// Keeps the best `k` of `best` and `hits`, in ranking order.
fn keep_best(best: &mut Vec<ScalHit>, hits: Vec<ScalHit>, k: usize) {
    best.extend(hits);
    top_k(best, k);
}
