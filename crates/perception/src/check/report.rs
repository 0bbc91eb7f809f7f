//! What `humem models check` found for one model, and the steps that fill
//! it in (load, graph facts, any error as the outcome).
//!
//! Its own module so that [`super::check_models`] and the OCR pair's checks
//! ([`super::text`]) both build reports without one using the other's
//! parent.

use std::path::PathBuf;

use ort::session::Session;

use super::graph::Facts;
use crate::config::{PerceptionConfig, Precision};
use crate::error::CheckError;
use crate::runtime;
use crate::signature::Io;

/// What `humem models check` found for one model.
#[derive(Debug)]
pub struct ModelReport {
    /// The model (`perception.descriptor`, …).
    pub model: &'static str,
    /// Its file, as resolved.
    pub file: Option<PathBuf>,
    /// Its precision.
    pub precision: Precision,
    /// What its graph declares, once loaded.
    pub io: Option<Io>,
    /// Notes of the graph check and the run.
    pub notes: Vec<String>,
    /// What one image gave, a line per output.
    pub ran: Vec<String>,
    /// Whether it fits.
    pub outcome: Result<(), CheckError>,
}

impl ModelReport {
    pub(super) fn new(model: &'static str, precision: Precision) -> ModelReport {
        ModelReport {
            model,
            file: None,
            precision,
            io: None,
            notes: Vec::new(),
            ran: Vec::new(),
            outcome: Ok(()),
        }
    }

    /// Records `result`'s error as the outcome, or gives its value.
    pub(super) fn record<T>(&mut self, result: Result<T, CheckError>) -> Option<T> {
        match result {
            Ok(value) => Some(value),
            Err(e) => {
                self.outcome = Err(e);
                None
            }
        }
    }

    /// Loads `model` at `precision` and reads its declared tensors.
    pub(super) fn load(
        &mut self,
        env: &ort::environment::Environment,
        config: &PerceptionConfig,
        model: &std::path::Path,
    ) -> Option<Session> {
        let name = self.model;
        let load = |error| CheckError::Load {
            model: name.to_string(),
            error,
        };
        let path = config
            .model_file(model, self.precision)
            .map_err(load)
            .inspect(|p| self.file = Some(p.clone()));
        let path = self.record(path)?;
        let session =
            runtime::session(env, &path, self.precision.options(config.session_options()));
        let session = self.record(session.map_err(load))?;
        self.io = Some(Io::of(&session));
        Some(session)
    }

    pub(super) fn facts(&mut self, facts: Result<Facts, CheckError>) -> Option<Option<usize>> {
        let facts = self.record(facts)?;
        self.notes.extend(facts.notes);
        Some(facts.descriptor_len)
    }
}
