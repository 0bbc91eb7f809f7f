//! The errors of loading and checking models.
//!
//! [`RuntimeError`] (ONNX Runtime or a model could not be loaded or run)
//! and [`CheckError`] (a model does not fit its configuration) hold each
//! other: a load is refused when its graph check fails, and a check
//! reports the load it could not make. So both live in this one leaf
//! module, which [`crate::runtime`] and [`crate::check`] use (and
//! re-export) instead of using each other.

use std::path::PathBuf;

use crate::signature::Kind;

/// Errors of loading ONNX Runtime or a model.
#[derive(Debug, Clone, thiserror::Error)]
pub enum RuntimeError {
    /// The ONNX Runtime shared library is not at the path resolved.
    #[error("ONNX Runtime library not found at {0}; run scripts/setup-models.sh or set perception.onnxruntime / ORT_DYLIB_PATH")]
    LibraryMissing(PathBuf),
    /// The library exists but could not be loaded or initialised.
    #[error("loading ONNX Runtime from {path}: {message}")]
    Library {
        /// The library's path.
        path: PathBuf,
        /// ONNX Runtime's message.
        message: String,
    },
    /// A configured model file does not exist.
    #[error("model file {0} does not exist; run scripts/setup-models.sh or fix the perception configuration")]
    ModelMissing(PathBuf),
    /// A model is configured with `precision = "int8"` and its quantised
    /// file is not beside the fp32 one.
    #[error("int8 model {0} does not exist; scripts/setup-models.sh makes it for the shipped models, tools/quantize_models.py for your own, or set the model's precision to \"fp32\"")]
    QuantizedMissing(PathBuf),
    /// The perception threads' nice value could not be set.
    #[error("setting perception.nice = {nice}: {message}")]
    Priority {
        /// The configured nice value.
        nice: i32,
        /// The system's message.
        message: String,
    },
    /// A model file (or the OCR dictionary) exists but could not be loaded.
    #[error("loading model {path}: {message}")]
    Model {
        /// The file's path.
        path: PathBuf,
        /// Why it could not be loaded.
        message: String,
    },
    /// A loaded model's graph does not fit its configuration (see
    /// [`crate::check`]).
    #[error(transparent)]
    Check(Box<CheckError>),
    /// A loaded model lacks a configured input or output, or an inference
    /// failed or gave outputs of an unexpected shape.
    #[error("model {model}: {message}")]
    Run {
        /// Which model: its role (`descriptor`, `ocr recognizer`, …).
        model: String,
        /// What went wrong.
        message: String,
    },
}

/// Why a model does not fit its configuration.
#[derive(Debug, Clone, thiserror::Error)]
pub enum CheckError {
    /// The model, a file it needs, or ONNX Runtime could not be loaded.
    #[error("{model}: {error}")]
    Load {
        /// The model (`perception.descriptor`, …).
        model: String,
        /// Why.
        error: RuntimeError,
    },
    /// The graph lacks a tensor the configuration names.
    #[error("{model}: the graph has no {kind} {tensor:?}; its {kind}s: {found}")]
    Missing {
        /// The model.
        model: String,
        /// Input or output.
        kind: Kind,
        /// The configured name.
        tensor: String,
        /// What the graph has instead.
        found: String,
    },
    /// A tensor is not what the configuration and HuMem need.
    #[error("{model}: {kind} {tensor:?} should be {expected}; found {found}")]
    Mismatch {
        /// The model.
        model: String,
        /// Input or output.
        kind: Kind,
        /// The tensor's name.
        tensor: String,
        /// What was expected, with the setting it comes from.
        expected: String,
        /// What the graph (or a run) has.
        found: String,
    },
    /// Running one image failed.
    #[error("{model}: running one {size} image through input {tensor:?} failed: {message}")]
    Run {
        /// The model.
        model: String,
        /// The input fed.
        tensor: String,
        /// The input's size, `WxH`.
        size: String,
        /// ONNX Runtime's (or HuMem's) message.
        message: String,
    },
}

impl CheckError {
    /// The model the error is about.
    pub fn model(&self) -> &str {
        match self {
            CheckError::Load { model, .. }
            | CheckError::Missing { model, .. }
            | CheckError::Mismatch { model, .. }
            | CheckError::Run { model, .. } => model,
        }
    }
}
