//! A query over a store shared with a writer: an exact pass over many rows
//! lets the index go between pieces of rows.
//!
//! A server keeps the index behind a readers-writer lock. A query through
//! the neighbour graph holds it for milliseconds; an exact pass over a
//! fleet's store (a query that asks for one, or `vpr.exact`) holds it for
//! hundreds, and meanwhile the store writer waits to publish, and every
//! query that starts after the writer began to wait waits behind it. So
//! such a pass reads [`PIECE_ROWS`] rows at a time
//! ([`PiecewiseScan`]), taking the index afresh for each piece; the writer
//! gets in between pieces. What it answers is what the one-hold pass
//! answers over the rows as each piece found them: rows appended meanwhile
//! are scanned last, in the hold that finishes the query (the layers after
//! SCAL and the rules). Row numbers carry across pieces: the writer puts
//! off grouping rows while a pass is under way ([`Index::hold_row_order`]),
//! and when a removal (or a grouping) renumbered rows meanwhile
//! ([`Index::renumberings`]) the pass starts over; after [`ATTEMPTS`] such
//! starts it holds the index for the whole pass.
//!
//! Everything else (a small eligible set, a query through the neighbour
//! graph, the f32 pass of a small store) is answered in the hold the
//! caller gives.

use std::ops::Deref;
use std::time::{Duration, Instant};

use crate::engine::filter::RowFilter;
use crate::engine::visit::Visit;
use crate::index::Index;
use crate::query::answer::{answer, answer_ranked, eligibility, Answer, IndexQuery};
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::params::VprParams;
use crate::vpr::piecewise::PiecewiseScan;
use crate::vpr::rank::rank_scanned;
use crate::vpr::scal::ScalQuery;
use crate::vpr::scan::codes_first_from;

#[cfg(test)]
#[path = "releasing_tests.rs"]
mod tests;

/// Rows a piece of a pass in pieces reads under one hold of the index:
/// 64 Ki rows, about 15 ms of both cores of a small server at 1280 values
/// a row, which is what the writer may wait.
pub const PIECE_ROWS: usize = 65_536;

/// Starts of a pass in pieces before it holds the index for the whole pass.
const ATTEMPTS: usize = 3;

/// [`answer`], letting the index go between pieces of an
/// exact pass over more than [`PIECE_ROWS`] rows (see the module doc).
/// `first` is a hold of the index the caller already has (it resolved the
/// query in it: `query.stored_row` is a row of it), `read` takes another.
/// Returns the hold the answer's rows belong to, for the caller to read
/// the candidates' keyframes in.
pub fn answer_releasing<G, R>(
    first: G,
    read: R,
    params: &VprParams,
    query: &IndexQuery,
) -> (G, Answer)
where
    G: Deref<Target = Index>,
    R: Fn() -> G,
{
    answer_in_pieces_of(PIECE_ROWS, first, read, params, query)
}

/// [`answer_releasing`] with pieces of `piece_rows` rows.
pub(crate) fn answer_in_pieces_of<G, R>(
    piece_rows: usize,
    first: G,
    read: R,
    params: &VprParams,
    query: &IndexQuery,
) -> (G, Answer)
where
    G: Deref<Target = Index>,
    R: Fn() -> G,
{
    let mut index = first;
    let mut query = query.clone();
    for _ in 0..ATTEMPTS {
        let Some(partition) = in_pieces(piece_rows, &index, params, &query) else {
            break;
        };
        match pass_in_pieces(piece_rows, index, partition, &read, params, &query) {
            Ok(answered) => return answered,
            Err(renumbered) => {
                index = renumbered;
                query.stored_row = query.stored_row.and_then(|_| stored_row(&index, &query));
            }
        }
    }
    let answer = answer(&index, params, &query);
    (index, answer)
}

/// The row of the stored keyframe the query names, in `index`.
fn stored_row(index: &Index, query: &IndexQuery) -> Option<usize> {
    let keyframe_id = query.context.keyframe_id?;
    index.row_of(&query.context.session.keyframe(keyframe_id))
}

/// Whether `query` makes an exact pass over more than `piece_rows` rows,
/// the codes first (the pass [`PiecewiseScan`] cuts into pieces); if so,
/// the partition it visits (None: every row), gathered once for the pass.
fn in_pieces(
    piece_rows: usize,
    index: &Index,
    params: &VprParams,
    query: &IndexQuery,
) -> Option<Option<Vec<usize>>> {
    if !(query.exact || params.exact) || query.observation.history.is_empty() {
        return None;
    }
    let eligible = eligibility(index, query);
    let partition = eligible.partition();
    let visited = partition.map_or(index.len(), <[usize]>::len);
    let matrix = index.descriptors();
    let rows = if matrix.in_memory() {
        visited
    } else {
        matrix.len()
    };
    (visited > piece_rows && codes_first_from(params.scan).is_some_and(|from| rows >= from))
        .then(|| partition.map(<[usize]>::to_vec))
}

/// The pass in pieces over `partition` (None: every row) as the hold
/// `first` has it, then the rest of the answer in the hold of the last
/// piece. Err: rows were renumbered; the hold that saw it, to start
/// over in.
fn pass_in_pieces<G, R>(
    piece_rows: usize,
    first: G,
    partition: Option<Vec<usize>>,
    read: &R,
    params: &VprParams,
    query: &IndexQuery,
) -> Result<(G, Answer), G>
where
    G: Deref<Target = Index>,
    R: Fn() -> G,
{
    let mut index = first;
    // The writer leaves the rows' order alone until the pass is done.
    let _order = index.hold_row_order();
    let numbering = index.renumberings();
    let stored_at_start = index.len();
    // The partition is as it was at the start: rows appended to it later
    // are past `stored_at_start`, scanned in the last piece.
    let visited = partition.as_ref().map_or(stored_at_start, Vec::len);
    let scal_query = ScalQuery {
        history: query.observation.history.clone(),
    };
    let Some(mut pass) = PiecewiseScan::new(params, &scal_query) else {
        let answer = answer(&index, params, query);
        return Ok((index, answer));
    };
    let mut scal_time = Duration::ZERO;
    let mut next = 0;
    loop {
        if index.renumberings() != numbering {
            return Err(index);
        }
        let eligible = eligibility(&index, query);
        let clock = Instant::now();
        let end = (next + piece_rows.max(1)).min(visited);
        let visit = match &partition {
            Some(rows) => Visit::Only(&rows[next..end]),
            None => Visit::Span(next, end - next),
        };
        pass.scan(params, &*index, &eligible, visit);
        next = end;
        if next < visited {
            scal_time += clock.elapsed();
            drop(eligible);
            drop(index);
            index = read();
            continue;
        }
        let appended = index.len() - stored_at_start;
        if appended > 0 {
            pass.scan(
                params,
                &*index,
                &eligible,
                Visit::Span(stored_at_start, appended),
            );
        }
        let scan = pass.finish(params, &*index);
        scal_time += clock.elapsed();
        let ranking = rank_scanned(
            params,
            query.layers,
            &query.observation,
            &*index,
            scan,
            scal_time,
        );
        let answer = answer_ranked(&index, params, query, ranking);
        return Ok((index, answer));
    }
}
