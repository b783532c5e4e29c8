//! Bindings of `mireg merge` and `mireg localize` ([`mireg::merge`]): options in, the report
//! as JSON out.

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use mireg::merge::{LocalizeOptions, LogLoops, MergeConfig, MergeOptions};

use crate::py_err;

/// `merge(runs, output_dir, force, seed, min_links, links_dir) -> str`: `mireg merge RUN... -o
/// DIR [--links LINKS_DIR]`; returns the report (`merge_report.json`) as JSON.
#[pyfunction]
#[pyo3(signature = (runs, output_dir, force=false, seed=0, min_links=2, links_dir=None))]
pub(crate) fn merge(
    py: Python<'_>,
    runs: Vec<std::path::PathBuf>,
    output_dir: std::path::PathBuf,
    force: bool,
    seed: u64,
    min_links: usize,
    links_dir: Option<std::path::PathBuf>,
) -> PyResult<String> {
    let opts = MergeOptions {
        runs,
        output_dir,
        force,
        seed,
        config: MergeConfig {
            min_links,
            ..MergeConfig::default()
        },
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
        links_dir,
    };
    let summary = py
        .detach(|| mireg::merge::merge(&opts))
        .map_err(|e| py_err(&e))?;
    serde_json::to_string(&summary).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// `localize(log, map, output, force, seed, min_links, topic, log_loops) -> str`: `mireg
/// localize LOG --map MAP -o OUTPUT`; `log_loops` is `"auto"` (default) or `"always"`, as
/// `--log-loops`; returns the summary as JSON.
#[pyfunction]
#[pyo3(signature = (log, map, output, force=false, seed=0, min_links=2, topic=None, log_loops="auto", map_reach_m=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn localize(
    py: Python<'_>,
    log: std::path::PathBuf,
    map: std::path::PathBuf,
    output: std::path::PathBuf,
    force: bool,
    seed: u64,
    min_links: usize,
    topic: Option<String>,
    log_loops: &str,
    map_reach_m: Option<f64>,
) -> PyResult<String> {
    let log_loops = match log_loops {
        "auto" => LogLoops::Auto,
        "always" => LogLoops::Always,
        other => {
            return Err(PyValueError::new_err(format!(
                "log_loops: {other:?}, expected \"auto\" or \"always\""
            )));
        }
    };
    let opts = LocalizeOptions {
        log,
        prior: map,
        output,
        force,
        seed,
        config: MergeConfig {
            min_links,
            ..MergeConfig::default()
        },
        topic,
        log_loops,
        map_reach_m,
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
    };
    let summary = py
        .detach(|| mireg::merge::localize(&opts))
        .map_err(|e| py_err(&e))?;
    serde_json::to_string(&summary).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}
