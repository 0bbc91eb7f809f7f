//! ONNX Runtime, loaded once per process, and sessions built on it.
//!
//! `ort` is used with `load-dynamic`: the shared library is the one the
//! setup step took from the PyPI `onnxruntime` wheel, found from the
//! configuration, `ORT_DYLIB_PATH`, or the models folder, in that order. ONNX
//! Runtime allows one environment per process, so it lives in a `OnceLock`.
//! Execution providers other than the CPU are opt-in (cargo features `cuda`
//! and `tensorrt`) and fall back to the CPU with a warning when they cannot
//! be registered, so a vehicle without a working GPU driver still serves.
//!
//! Its error, [`RuntimeError`], is defined in [`crate::error`] beside the
//! model check's error it can carry, and re-exported here.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ort::session::builder::GraphOptimizationLevel;
use ort::session::Session;
use serde::{Deserialize, Serialize};

pub use crate::error::RuntimeError;

/// The hardware a model runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ExecutionProvider {
    /// The CPU, always available.
    #[default]
    Cpu,
    /// An NVIDIA GPU through CUDA (cargo feature `cuda`).
    Cuda,
    /// An NVIDIA GPU through TensorRT (cargo feature `tensorrt`).
    Tensorrt,
}

static ENVIRONMENT: OnceLock<Result<ort::environment::Environment, RuntimeError>> = OnceLock::new();

/// Where the ONNX Runtime library is: `configured` if set, else
/// `ORT_DYLIB_PATH`, else `<models_dir>/lib/libonnxruntime.so`.
pub fn library_path(configured: Option<&Path>, models_dir: &Path) -> PathBuf {
    if let Some(path) = configured {
        return path.to_path_buf();
    }
    if let Some(path) = std::env::var_os("ORT_DYLIB_PATH") {
        return PathBuf::from(path);
    }
    models_dir.join("lib").join(library_file_name())
}

fn library_file_name() -> &'static str {
    if cfg!(target_os = "macos") {
        "libonnxruntime.dylib"
    } else if cfg!(windows) {
        "onnxruntime.dll"
    } else {
        "libonnxruntime.so"
    }
}

/// The process's ONNX Runtime environment, loading the library on first use.
/// Later calls return the first result whatever `library` they name.
pub fn environment(library: &Path) -> Result<ort::environment::Environment, RuntimeError> {
    ENVIRONMENT
        .get_or_init(|| {
            if !library.exists() {
                return Err(RuntimeError::LibraryMissing(library.to_path_buf()));
            }
            let error = |message: String| RuntimeError::Library {
                path: library.to_path_buf(),
                message,
            };
            let builder = ort::init_from(library).map_err(|e| error(e.to_string()))?;
            let env = builder
                .with_name("humem")
                .build()
                .map_err(|e| error(e.to_string()))?;
            tracing::info!(library = %library.display(), "ONNX Runtime loaded");
            Ok(env)
        })
        .clone()
}

/// Settings of the sessions of one model.
#[derive(Debug, Clone, Copy)]
pub struct SessionOptions {
    /// Where inference runs; falls back to the CPU when unavailable.
    pub provider: ExecutionProvider,
    /// Threads ONNX Runtime may use inside one inference; 0 = its default.
    pub intra_threads: usize,
    /// The model is an int8 quantisation: on an x86 CPU without VNNI, its
    /// products run in ONNX Runtime's precise mode ([`needs_precise_int8`]).
    pub int8: bool,
}

/// Whether int8 models must run in ONNX Runtime's precise mode here. On
/// x86 CPUs without VNNI (AVX2 only: Haswell to Skylake client, Zen 2/3)
/// its fast uint8 × int8 kernels saturate 16-bit intermediate sums: under
/// emulation of such a CPU the int8 descriptor fell to cosine 0.84 of the
/// VNNI result, and text lines read differently. The precise mode
/// (`session.x64quantprecision`) gives the VNNI results bit for bit there,
/// slower; with VNNI it changes nothing and costs time, so it is set only
/// where needed.
pub fn needs_precise_int8() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        !(std::arch::is_x86_feature_detected!("avx512vnni")
            || std::arch::is_x86_feature_detected!("avxvnni"))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Loads a model.
pub fn session(
    env: &ort::environment::Environment,
    path: &Path,
    options: SessionOptions,
) -> Result<Session, RuntimeError> {
    if !path.exists() {
        return Err(RuntimeError::ModelMissing(path.to_path_buf()));
    }
    let error = |message: String| RuntimeError::Model {
        path: path.to_path_buf(),
        message,
    };
    let mut builder = Session::builder(env)
        .map_err(|e| error(e.to_string()))?
        .with_optimization_level(GraphOptimizationLevel::All)
        .unwrap_or_else(|e| e.recover());
    if options.intra_threads > 0 {
        builder = builder
            .with_intra_threads(options.intra_threads)
            .map_err(|e| error(e.to_string()))?;
    }
    if options.int8 && needs_precise_int8() {
        builder = builder
            .with_precise_qmm()
            .map_err(|e| error(e.to_string()))?;
        tracing::warn!(
            model = %path.display(),
            "this CPU has no VNNI: the int8 model runs in ONNX Runtime's precise mode, slower than fp32 here; set its precision to \"fp32\" for speed"
        );
    }
    builder = with_provider(builder, options.provider, path);
    builder
        .commit_from_file(path)
        .map_err(|e| error(e.to_string()))
}

/// Registers the configured execution provider, or says why not and stays
/// on the CPU.
fn with_provider(
    builder: ort::session::builder::SessionBuilder,
    provider: ExecutionProvider,
    path: &Path,
) -> ort::session::builder::SessionBuilder {
    let dispatch: Option<ort::ep::ExecutionProviderDispatch> = match provider {
        ExecutionProvider::Cpu => None,
        #[cfg(feature = "cuda")]
        ExecutionProvider::Cuda => Some(ort::ep::CUDA::default().build().error_on_failure()),
        #[cfg(feature = "tensorrt")]
        ExecutionProvider::Tensorrt => {
            Some(ort::ep::TensorRT::default().build().error_on_failure())
        }
        #[allow(unreachable_patterns)]
        other => {
            tracing::warn!(
                model = %path.display(),
                provider = ?other,
                "this build has no support for the configured execution provider (cargo feature `cuda` or `tensorrt`); running on the CPU"
            );
            None
        }
    };
    let Some(dispatch) = dispatch else {
        return builder;
    };
    match builder.with_execution_providers([dispatch]) {
        Ok(builder) => {
            tracing::info!(model = %path.display(), ?provider, "execution provider registered");
            builder
        }
        Err(e) => {
            tracing::warn!(
                model = %path.display(),
                ?provider,
                error = %e,
                "execution provider unavailable; running on the CPU"
            );
            e.recover()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg(all(target_os = "linux", target_arch = "x86_64"))]
    fn precise_int8_is_asked_for_exactly_where_the_cpu_has_no_vnni() {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap();
        let flags: Vec<&str> = cpuinfo
            .lines()
            .find(|l| l.starts_with("flags"))
            .unwrap()
            .split_whitespace()
            .collect();
        let vnni = flags.contains(&"avx512_vnni") || flags.contains(&"avx_vnni");
        assert_eq!(needs_precise_int8(), !vnni, "{flags:?}");
    }
}
