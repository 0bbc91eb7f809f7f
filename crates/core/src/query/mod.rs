//! One query over the index, from the eligible rows to the selected
//! candidates.
//!
//! The scan and the paper's layers rank the eligible rows
//! ([`rank_timed`](crate::vpr::rank::rank_timed)); the rules on top of them that need the index itself
//! come next, in this order: views of the query's own map turned away from
//! it are left out ([`viewpoint`](crate::vpr::viewpoint)), its candidates lying farther away
//! than the map's drift explains lose score ([`drift`](crate::vpr::drift)),
//! SLAM's verdicts change the scores
//! ([`feedback`](crate::vpr::feedback)), where asked those still beyond the drift envelope
//! below one within it are left out ([`leave_out_rivals_beyond_drift`]),
//! and the store's operating point gives the threshold
//! unless the query names one; then the candidates are selected.
//!
//! It lives in the core, beside the ranking, so that a query goes down once
//! and comes back once: the server resolves what the query is before (the
//! features it sent or the stored keyframe it names, its context and
//! temporal history) and spells the evidence out after, and never steps in
//! between the scan and the selection. The rules' time is booked as the
//! `rules` stage of [`StageTimes`](crate::vpr::rank::StageTimes).
//!
//! [`answer`] reads an index held as it is (`answer`); a server, whose
//! index a writer shares, calls [`answer_releasing`] (`releasing`), which
//! lets the index go between pieces of an exact pass over a large store
//! and answers everything else as `answer` does.

mod answer;
mod releasing;

pub use answer::{
    answer, apply_verdicts, leave_out_rivals_beyond_drift, leave_out_turned_away,
    lower_beyond_drift, Answer, IndexQuery,
};
pub use releasing::{answer_releasing, PIECE_ROWS};
