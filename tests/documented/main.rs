//! Documented examples run as written. They take the fixed ports the docs
//! name, so they are a test binary of their own: cargo runs test binaries
//! one after another, and no other test's server or client can hold one of
//! those ports (an ephemeral port is any in 32768-60999) while they run.

#[allow(dead_code)]
#[path = "../e2e/harness.rs"]
mod harness;
#[allow(dead_code)]
#[path = "../e2e/nats.rs"]
mod nats;

mod cluster;
