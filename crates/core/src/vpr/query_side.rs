//! The query side of a SCAL pass, prepared once per query: its
//! descriptors, scene profiles and thumbnails, and the per-row products
//! every pass (exact, compressed, approximate) computes from them.
//!
//! Kept apart from the passes themselves ([`super::scan`]) so that each
//! pass reads as its plan, and the arithmetic they share is one copy.

use rayon::prelude::*;

use crate::engine::codes::QueryCode;
use crate::engine::kernels::CodeKernel;
use crate::engine::matrix::multi_dot;
use crate::keyframe::Features;
use crate::vpr::appearance;
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::params::VprParams;
use crate::vpr::scal::{temporal_hit, ScalHit, SceneProfile, STEPS};

/// The query side, prepared once: descriptors, scene profiles and
/// thumbnails of up to [`STEPS`] observations.
pub(super) struct QuerySide<'a> {
    pub(super) descriptors: Vec<&'a [f32]>,
    pub(super) scenes: Vec<SceneProfile>,
    thumbnails: [Option<(&'a [i8], f32)>; STEPS],
    pub(super) with_thumbnails: bool,
    weight: f32,
}

impl<'a> QuerySide<'a> {
    pub(super) fn new(params: &VprParams, history: &[&'a Features]) -> Self {
        let steps = history.len().min(STEPS);
        let weight = params.appearance_weight;
        let thumbnails: [Option<(&[i8], f32)>; STEPS] = std::array::from_fn(|j| {
            let t = history.get(j).map(|f| f.appearance.as_slice())?;
            (weight > 0.0 && t.len() == appearance::LEN)
                .then(|| (t, appearance::norm(t)))
                .filter(|&(_, norm)| norm > 0.0)
        });
        QuerySide {
            descriptors: history[..steps]
                .iter()
                .map(|f| f.descriptor.as_slice())
                .collect(),
            scenes: history[..steps]
                .iter()
                .map(|f| SceneProfile::new(&f.scene))
                .collect(),
            with_thumbnails: thumbnails.iter().any(Option::is_some),
            thumbnails,
            weight,
        }
    }

    /// The one-byte codes of the query's descriptors, for `memory`'s code
    /// matrix and `kernel`.
    pub(super) fn codes<M: KeyframeMemory + ?Sized>(
        &self,
        memory: &M,
        kernel: CodeKernel,
    ) -> Vec<QueryCode> {
        let matrix = memory.descriptors().codes();
        self.descriptors
            .iter()
            .map(|q| QueryCode::new(q, matrix, kernel))
            .collect()
    }

    pub(super) fn steps(&self) -> usize {
        self.descriptors.len()
    }

    /// `s_e` of step `j` for a row whose descriptor product is `dot`.
    pub(super) fn fused<M: KeyframeMemory + ?Sized>(
        &self,
        memory: &M,
        row: usize,
        j: usize,
        dot: f32,
    ) -> f32 {
        let stored = if self.with_thumbnails {
            memory.appearance().row(row)
        } else {
            None
        };
        let rho = stored
            .zip(self.thumbnails[j])
            .map(|(c, q)| appearance::similarity(q, c));
        appearance::fused(dot, rho, self.weight)
    }

    /// `s_e(Q_{t−j}, row)` for every step, from one fused read of the f32
    /// row `r` (0 beyond the query's history).
    pub(super) fn exact_row<M: KeyframeMemory + ?Sized>(
        &self,
        memory: &M,
        row: usize,
        r: &[f32],
    ) -> [f32; STEPS] {
        let q = &self.descriptors;
        let dots = match self.steps() {
            0 => [0.0; STEPS],
            1 => {
                let [a] = multi_dot(&[q[0]], r);
                [a, 0.0, 0.0]
            }
            2 => {
                let [a, b] = multi_dot(&[q[0], q[1]], r);
                [a, b, 0.0]
            }
            _ => multi_dot(&[q[0], q[1], q[2]], r),
        };
        std::array::from_fn(|j| self.fused(memory, row, j, dots[j]))
    }

    /// Upper bounds on `s_e(Q_{t−j}, row)` from the codes, for the rows
    /// from `first` on, one per entry of `out` (`bounds` is scratch space).
    pub(super) fn upper_rows<M: KeyframeMemory + ?Sized>(
        &self,
        memory: &M,
        codes: &[QueryCode],
        kernel: CodeKernel,
        first: usize,
        bounds: &mut Vec<[(f32, f32); STEPS]>,
        out: &mut [[f32; STEPS]],
    ) {
        // A history shorter than STEPS repeats its last query: the extra
        // products are never read (`temporal_hit` stops at the history's
        // length), and one kernel shape serves every query.
        let last = codes.len() - 1;
        let query = |j: usize| &codes[j.min(last)];
        let matrix = memory.descriptors().codes();
        if !self.with_thumbnails {
            // Without thumbnails `s_e` is the clipped product: one pass
            // straight from the kernel's sums, branch-free.
            matrix.upper_bounds_rows(kernel, first, &[query(0), query(1), query(2)], out);
            for o in out.iter_mut().flatten() {
                *o = clip01_branchless(*o) * (1.0 + 1e-6);
            }
            return;
        }
        bounds.clear();
        bounds.resize(out.len(), [(0.0, 0.0); STEPS]);
        matrix.dot_bounds_rows(kernel, first, &[query(0), query(1), query(2)], bounds);
        // The relative margin covers the scene modulation's rounding: the
        // loose bound skips it, and (1 + λc)/(1 + λ) at c = 1 can round a
        // hair above 1. [`QuerySide::pair_bounds`] does the same for one.
        for (i, (o, b)) in out.iter_mut().zip(bounds.iter()).enumerate() {
            *o = std::array::from_fn(|j| {
                let (estimate, bound) = b[j];
                self.fused(memory, first + i, j, estimate + bound) * (1.0 + 1e-6)
            });
        }
    }

    /// Lower and upper bounds on `s_e(Q_{t−j}, row)` from the codes; the
    /// upper one as [`QuerySide::upper_rows`] computes it.
    pub(super) fn pair_bounds<M: KeyframeMemory + ?Sized>(
        &self,
        memory: &M,
        codes: &[QueryCode],
        kernel: CodeKernel,
        row: usize,
        j: usize,
    ) -> (f32, f32) {
        let m = memory.descriptors().codes();
        let [(estimate, bound)] = m.dot_bounds(kernel, row, &[&codes[j]]);
        (
            self.fused(memory, row, j, estimate - bound),
            self.fused(memory, row, j, estimate + bound) * (1.0 + 1e-6),
        )
    }

    /// `s_e` of step `j` and `row` from the codes' estimate of their
    /// product.
    pub(super) fn pair_estimate<M: KeyframeMemory + ?Sized>(
        &self,
        memory: &M,
        codes: &[QueryCode],
        kernel: CodeKernel,
        row: usize,
        j: usize,
    ) -> f32 {
        let m = memory.descriptors().codes();
        let [(estimate, _)] = m.dot_bounds(kernel, row, &[&codes[j]]);
        self.fused(memory, row, j, estimate)
    }

    /// The exact hit of `row`, following its predecessors, whose products
    /// `table` holds.
    pub(super) fn exact_hit<M: KeyframeMemory + ?Sized>(
        &self,
        params: &VprParams,
        memory: &M,
        table: &ExactTable,
        row: usize,
    ) -> ScalHit {
        temporal_hit(params, memory, self.steps(), row, |c, j| {
            (
                table.get(c)[j],
                self.scenes[j].compatibility(memory.scene(c)),
            )
        })
    }

    /// The exact hits of `rows`, in their order: the rows and their chains
    /// read once each ([`ExactTable`]).
    pub(super) fn exact_hits<M: KeyframeMemory + ?Sized>(
        &self,
        params: &VprParams,
        memory: &M,
        rows: &[usize],
    ) -> Vec<ScalHit> {
        let table = ExactTable::new(self, memory, rows);
        rows.par_iter()
            .with_min_len(PARALLEL_MIN_ROWS)
            .map(|&row| self.exact_hit(params, memory, &table, row))
            .collect()
    }
}

/// The fewest rows scored exactly that are split across the scan
/// threads: below it they are scored on the query's own thread. A row
/// costs a few microseconds, and handing work to the pool and waiting for
/// it costs tens, with a sleep and a wake-up of each thread: a fleet
/// server runs a query per core at once, and scoring a neighbour graph's
/// few hundred candidates across the pool only added switches.
const PARALLEL_MIN_ROWS: usize = 1024;

/// Exact `s_e` of every step for a set of rows and the rows of their
/// chains, each row read once, in row order. A row is in the chains of up
/// to [`STEPS`] scored rows; reading it once per query instead of once per
/// chain matters when the f32 rows are in a file, where each read is a
/// system call.
pub(super) struct ExactTable {
    rows: Vec<usize>,
    s_e: Vec<[f32; STEPS]>,
}

impl ExactTable {
    pub(super) fn new<M: KeyframeMemory + ?Sized>(
        side: &QuerySide,
        memory: &M,
        rows: &[usize],
    ) -> Self {
        let matrix = memory.descriptors();
        let mut needed = Vec::with_capacity(rows.len() * side.steps());
        for &row in rows {
            // The rows `temporal_hit` visits: the row, then predecessors.
            let mut c = row;
            needed.push(c);
            for _ in 1..side.steps() {
                match memory.predecessor(c) {
                    Some(p) if p < matrix.len() => c = p,
                    _ => break,
                }
                needed.push(c);
            }
        }
        needed.sort_unstable();
        needed.dedup();
        let s_e = needed
            .par_iter()
            .with_min_len(PARALLEL_MIN_ROWS)
            .map(|&c| side.exact_row(memory, c, &matrix.row(c)))
            .collect();
        ExactTable { rows: needed, s_e }
    }

    /// The products of chain row `c`. Panics if it is not in the table.
    fn get(&self, c: usize) -> &[f32; STEPS] {
        let i = self
            .rows
            .binary_search(&c)
            .expect("a chain row of a scored row");
        &self.s_e[i]
    }
}

/// [`clip01`](crate::numeric::clip01) written so that a loop of it
/// vectorises: the same value for every input, NaN and −0 to +0 included
/// (`max` returns its other operand for NaN; adding +0 turns −0 into +0).
#[inline(always)]
pub(super) fn clip01_branchless(x: f32) -> f32 {
    (x.max(0.0) + 0.0).min(1.0)
}
