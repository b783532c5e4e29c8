//! `mireg._mireg`: the compiled half of the `mireg` Python package (`python/mireg/`), thin
//! bindings over the `mireg` crate. The Python half turns keyword arguments into the CLI's
//! configuration and JSON results into typed objects; everything that computes runs here with
//! the GIL released.
//!
//! Results are those of the `mireg` command for the same configuration and seed, bit for bit:
//! `register_pair` calls what `mireg pair` calls and returns the same JSON object;
//! `register_log` fills the library's settings by flag name ([`RegisterSettings`], as `mireg
//! register` fills them from its flags) and runs the options they give.

mod command;
mod run;
mod sessions;

use std::sync::Mutex;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use nalgebra::Point3;
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use mireg::cli::pair_json;
use mireg::odometry::OdometryConfig;
use mireg::odometry::stream::StreamOdometry;
use mireg::pipeline::{PairConfig, register_pair as pair};
use mireg::register::{OnFrame, RegisterSettings, for_each_cloud, register_log as run_log};

/// A mireg error as the Python exception a user expects: `OSError` for files, `ValueError` for
/// bad input, `RuntimeError` otherwise; the message is the CLI's.
pub(crate) fn py_err(e: &mireg::Error) -> PyErr {
    let text = e.to_string();
    match e {
        mireg::Error::Io { .. } => PyOSError::new_err(text),
        mireg::Error::InvalidInput(_) | mireg::Error::Format { .. } => PyValueError::new_err(text),
        _ => PyRuntimeError::new_err(text),
    }
}

/// The points of an `(N, 3)` C-contiguous float64 array, without a copy (`Point3<f64>` is
/// `[f64; 3]`).
fn points<'a>(a: &'a PyReadonlyArray2<'_, f64>, name: &str) -> PyResult<&'a [Point3<f64>]> {
    let shape = a.shape();
    if shape[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "{name}: expected an (N, 3) array of points, got shape ({}, {})",
            shape[0], shape[1]
        )));
    }
    let flat = a
        .as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name}: the array is not C-contiguous")))?;
    // SAFETY: Point3<f64> is #[repr(C)] over [f64; 3]; `flat` holds 3·N f64 values.
    Ok(unsafe { std::slice::from_raw_parts(flat.as_ptr().cast::<Point3<f64>>(), shape[0]) })
}

/// `register_pair(source, target, config_json) -> str`: registers `source` onto `target`
/// (`(N, 3)` float64 arrays, metres) with the pair configuration given as JSON (the TOML
/// configuration's fields), and returns `mireg pair --json`'s object as JSON.
#[pyfunction]
fn register_pair(
    py: Python<'_>,
    source: PyReadonlyArray2<'_, f64>,
    target: PyReadonlyArray2<'_, f64>,
    config_json: &str,
) -> PyResult<String> {
    // As `mireg pair`: the allocator keeps freed blocks for reuse instead of returning each
    // multi-megabyte buffer to the kernel (src/heap.rs); without it a pair costs 10–25 % more.
    static KEEP_FREED: std::sync::Once = std::sync::Once::new();
    KEEP_FREED.call_once(mireg::heap::keep_freed_memory);
    let config: PairConfig = serde_json::from_str(config_json)
        .map_err(|e| PyValueError::new_err(format!("configuration: {e}")))?;
    let (s, t) = (points(&source, "source")?, points(&target, "target")?);
    let result = py.detach(|| pair(s, t, &config)).map_err(|e| py_err(&e))?;
    Ok(pair_json(&result, None).to_string())
}

/// The default pair configuration as JSON, for the Python side to overlay keyword arguments on.
#[pyfunction]
fn default_pair_config() -> String {
    serde_json::to_string(&PairConfig::default()).expect("PairConfig serialises")
}

/// The default settings of `register_log` as JSON (`mireg register`'s flags by name, at their
/// defaults), for the Python side to check keyword arguments against.
#[pyfunction]
fn default_register_settings() -> String {
    serde_json::to_string(&RegisterSettings::default()).expect("RegisterSettings serialises")
}

/// `register_log(path, output, settings_json, progress) -> str`: `mireg register PATH` into
/// `output` (default `PATH.mireg.mcap` beside it) with the settings given as JSON (the flags'
/// names and values, [`RegisterSettings`]), without a progress bar; `progress(frames_written,
/// frames_in_log)` is called after each frame (an exception it raises is printed, not raised:
/// the run goes on). Returns the `--json` summary.
#[pyfunction]
#[pyo3(signature = (path, output, settings_json, progress=None))]
fn register_log(
    py: Python<'_>,
    path: std::path::PathBuf,
    output: Option<std::path::PathBuf>,
    settings_json: &str,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    let settings = RegisterSettings::from_json(settings_json).map_err(|e| py_err(&e))?;
    let mut opts = settings
        .options(&path, output.as_deref())
        .map_err(|e| py_err(&e))?;
    // As `mireg register` records its own: this process's command line.
    opts.command_line = std::env::args().collect::<Vec<_>>().join(" ");
    opts.progress = false;
    if let Some(callback) = progress {
        opts.on_frame = Some(OnFrame(std::sync::Arc::new(move |done, total| {
            Python::attach(|py| {
                if let Err(e) = callback.call1(py, (done, total)) {
                    e.print(py);
                }
            })
        })));
    }
    let summary = py.detach(|| run_log(&opts)).map_err(|e| py_err(&e))?;
    serde_json::to_string(&summary).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// One decoded cloud: header stamp [ns], points, intensity, per-point times [s after the stamp],
/// log time [ns], frame id.
type CloudMsg = (
    i64,
    Vec<Point3<f64>>,
    Option<Vec<f32>>,
    Option<Vec<f64>>,
    u64,
    String,
);

/// What the Python iterator yields: `(stamp_ns, points, fields)`.
type PyCloud<'py> = (i64, Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>);

/// The clouds of a log, read on a thread of their own and handed over at most two ahead, so a
/// log of any length is read in bounded memory.
#[pyclass(module = "mireg._mireg")]
struct CloudReader {
    rx: Option<Mutex<Receiver<mireg::Result<CloudMsg>>>>,
    thread: Option<JoinHandle<()>>,
    topic: String,
    /// Log time [ns] and frame id of the cloud yielded last.
    last: (u64, String),
}

#[pymethods]
impl CloudReader {
    /// Opens `path` (any log `register` reads) and starts reading the cloud topic (`topic`, or
    /// the only one).
    #[new]
    #[pyo3(signature = (path, topic=None))]
    fn new(py: Python<'_>, path: std::path::PathBuf, topic: Option<String>) -> PyResult<Self> {
        // The topic is chosen (and errors reported) before the thread starts.
        let (log, catalog) = mireg::io::input_log::InputLog::open(&path).map_err(|e| py_err(&e))?;
        drop(log);
        let chosen =
            mireg::register::point_cloud_topic(&path, &catalog.channel_infos(), topic.as_deref())
                .map_err(|e| py_err(&e))?;
        let (tx, rx): (SyncSender<mireg::Result<CloudMsg>>, _) = sync_channel(2);
        let topic_arg = chosen.clone();
        let thread = py.detach(|| {
            std::thread::spawn(move || {
                let sent = for_each_cloud(&path, Some(&topic_arg), |log_time, c| {
                    let msg = (
                        c.header.stamp.to_ns(),
                        c.points,
                        c.intensity,
                        c.times.map(|t| t.seconds),
                        log_time,
                        c.header.frame_id,
                    );
                    match tx.send(Ok(msg)) {
                        Ok(()) => Ok(std::ops::ControlFlow::Continue(())),
                        // The Python iterator was dropped: stop reading.
                        Err(_) => Ok(std::ops::ControlFlow::Break(())),
                    }
                });
                if let Err(e) = sent {
                    let _ = tx.send(Err(e));
                }
            })
        });
        Ok(Self {
            rx: Some(Mutex::new(rx)),
            thread: Some(thread),
            topic: chosen,
            last: (0, String::new()),
        })
    }

    /// The cloud topic being read.
    #[getter]
    fn topic(&self) -> &str {
        &self.topic
    }

    /// The log time \[ns\] of the cloud yielded last (0 before the first).
    #[getter]
    fn log_time(&self) -> u64 {
        self.last.0
    }

    /// The header `frame_id` of the cloud yielded last (empty before the first).
    #[getter]
    fn frame_id(&self) -> &str {
        &self.last.1
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// `(stamp_ns, points (N, 3) float64, fields)`; `fields` holds `intensity` (float32) and
    /// `time` (float64, seconds after the stamp) when the cloud has them.
    fn __next__<'py>(&mut self, py: Python<'py>) -> PyResult<Option<PyCloud<'py>>> {
        let Some(rx) = &self.rx else { return Ok(None) };
        let next = py.detach(|| {
            rx.lock()
                .map_err(|_| ())
                .and_then(|r| r.recv().map_err(|_| ()))
        });
        let Ok(msg) = next else {
            self.close();
            return Ok(None);
        };
        let (stamp, pts, intensity, times, log_time, frame_id) = msg.map_err(|e| py_err(&e))?;
        self.last = (log_time, frame_id);
        let n = pts.len();
        let flat: Vec<f64> = pts.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        let array = PyArray1::from_vec(py, flat).reshape([n, 3])?;
        let fields = PyDict::new(py);
        if let Some(i) = intensity {
            fields.set_item("intensity", PyArray1::from_vec(py, i))?;
        }
        if let Some(t) = times {
            fields.set_item("time", PyArray1::from_vec(py, t))?;
        }
        Ok(Some((stamp, array, fields)))
    }

    /// Stops reading (also when the iterator is dropped or exhausted).
    fn close(&mut self) {
        self.rx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for CloudReader {
    fn drop(&mut self) {
        self.close();
    }
}

/// `mireg register`'s odometry fed one cloud at a time ([`StreamOdometry`]).
#[pyclass(module = "mireg._mireg")]
struct Odometry {
    inner: Mutex<StreamOdometry>,
    frames: usize,
}

#[pymethods]
impl Odometry {
    /// Odometry with the configuration given as JSON (`OdometryConfig`'s fields; the voxel from
    /// the first cloud when `derive_voxel`; clouds with times deskewed when `deskew`).
    #[new]
    fn new(config_json: &str, derive_voxel: bool, deskew: bool) -> PyResult<Self> {
        let config: OdometryConfig = serde_json::from_str(config_json)
            .map_err(|e| PyValueError::new_err(format!("configuration: {e}")))?;
        Ok(Self {
            inner: Mutex::new(StreamOdometry::new(config, derive_voxel, deskew)),
            frames: 0,
        })
    }

    /// Registers the next cloud: `(N, 3)` float64 points, per-point `times` in seconds after
    /// `stamp_ns` when known; returns `(world_from_frame 4×4 as 16 row-major values, estimate
    /// JSON)`.
    #[pyo3(signature = (points, times, stamp_ns))]
    fn register_frame(
        &mut self,
        py: Python<'_>,
        points: PyReadonlyArray2<'_, f64>,
        times: Option<numpy::PyReadonlyArray1<'_, f64>>,
        stamp_ns: i64,
    ) -> PyResult<(Vec<f64>, String)> {
        let pts = self::points(&points, "points")?.to_vec();
        let times = match &times {
            Some(t) => {
                let t = t.as_slice().map_err(|_| {
                    PyValueError::new_err("timestamps: the array is not contiguous")
                })?;
                if t.len() != pts.len() {
                    return Err(PyValueError::new_err(format!(
                        "timestamps: {} values for {} points",
                        t.len(),
                        pts.len()
                    )));
                }
                Some(t.to_vec())
            }
            None => None,
        };
        let inner = &self.inner;
        let est = py
            .detach(|| {
                let mut odometry = inner.lock().expect("odometry lock");
                odometry.push(pts, times.as_deref(), stamp_ns)
            })
            .map_err(|e| py_err(&e))?;
        self.frames += 1;
        let m = est.world_from_frame.to_homogeneous();
        let rows = (0..4)
            .flat_map(|r| (0..4).map(move |c| m[(r, c)]))
            .collect();
        let info = serde_json::json!({
            "success": est.success,
            "failure_reason": est.failure.map(|f| f.as_str()),
            "num_points": est.num_points,
            "num_points_downsampled": est.num_points_downsampled,
        });
        Ok((rows, info.to_string()))
    }

    /// The configuration in use, as JSON (resolved by the first cloud).
    fn config_json(&self) -> String {
        let inner = self.inner.lock().expect("odometry lock");
        serde_json::to_string(inner.config()).expect("OdometryConfig serialises")
    }

    /// The default odometry configuration, as JSON.
    #[staticmethod]
    fn default_config_json() -> String {
        serde_json::to_string(&OdometryConfig::default()).expect("OdometryConfig serialises")
    }
}

/// The compiled module.
#[pymodule]
fn _mireg(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(command::cli_main, m)?)?;
    m.add_function(wrap_pyfunction!(run::channels, m)?)?;
    m.add_function(wrap_pyfunction!(run::read_pose_topics, m)?)?;
    m.add_function(wrap_pyfunction!(run::read_json_topics, m)?)?;
    m.add_function(wrap_pyfunction!(run::evaluate_topics, m)?)?;
    m.add_function(wrap_pyfunction!(register_pair, m)?)?;
    m.add_function(wrap_pyfunction!(default_pair_config, m)?)?;
    m.add_function(wrap_pyfunction!(default_register_settings, m)?)?;
    m.add_function(wrap_pyfunction!(register_log, m)?)?;
    m.add_function(wrap_pyfunction!(sessions::merge, m)?)?;
    m.add_function(wrap_pyfunction!(sessions::localize, m)?)?;
    m.add_class::<CloudReader>()?;
    m.add_class::<Odometry>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
