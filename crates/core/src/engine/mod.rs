//! The scan engine: where the stored descriptors live and the inner loops
//! that read them.
//!
//! A query at fleet scale is one pass over every eligible descriptor, so
//! the layout of the rows and the kernels over them decide its cost. They
//! know nothing of HuMem-VPR's scores; the scoring layers in [`crate::vpr`]
//! build on them.
//!
//! - [`matrix`]: the contiguous row-major descriptor matrix and its f32 dot
//!   products;
//! - [`codes`]: the rows' one-byte codes with a bound on their error, so a
//!   large store's scan can read a quarter of the bytes and still return the
//!   exact answer;
//! - [`kernels`]: the SIMD inner loops (AVX-512 VNNI, AVX2, portable),
//!   chosen once at run time;
//! - [`row_file`]: where the f32 rows go when they leave memory (the one
//!   file I/O of the core: positional reads and writes);
//! - [`graph`]: the neighbour graph (HNSW) that proposes a large query's
//!   candidates without reading every row;
//! - [`projection`]: the fixed random rotation that shortens descriptors
//!   for the graph, so that its inserts cost a fraction;
//! - [`filter`]: what a scan asks of the eligibility rule (a test per row
//!   and, where known, the rows that can pass);
//! - `visit`: which rows a scan visits, in blocks for the cores and runs of
//!   consecutive rows.

pub mod codes;
pub mod filter;
pub mod graph;
pub mod kernels;
pub mod matrix;
pub mod projection;
pub mod row_file;
pub(crate) mod visit;
