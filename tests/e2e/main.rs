//! End-to-end tests: they start the real `humem` binary on a free loopback
//! port with a temporary data directory and drive it through the generated
//! tonic client, as a SLAM system would.

mod harness;
mod nats;
mod pki;
mod scenes;

mod admission;
mod auth;
mod cli;
mod cluster;
mod cpu;
mod detector;
mod durability;
mod errors;
mod eval;
mod fidelity;
mod full_disk;
mod images;
mod latest_wins;
mod maintenance;
mod metrics;
mod models_check;
mod quotas;
mod recordings;
mod retrieval;
mod text_recall;
mod tls;
mod verdicts;
