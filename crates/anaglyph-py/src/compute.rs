//! Running the core: without the GIL, on the thread pool `set_num_threads` chose, with
//! any Rust panic caught and raised as `InternalError`.
//!
//! The work runs on a thread of its own while the calling thread waits for it and, every
//! [`SIGNAL_CHECK_INTERVAL`], lets Python handle signals: a Ctrl-C raises
//! `KeyboardInterrupt` in the caller, and a call that supports it (`reconstruct`) is told
//! to stop at its next stage boundary; other calls finish first.

use crate::errors::{internal, to_py};
use pyo3::prelude::*;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

/// How often a waiting call lets Python handle signals.
const SIGNAL_CHECK_INTERVAL: Duration = Duration::from_millis(100);

/// The pool compute calls run on (None: rayon's global pool, one thread per core).
static POOL: Mutex<Option<Arc<rayon::ThreadPool>>> = Mutex::new(None);

/// The pool in use.
fn pool() -> Option<Arc<rayon::ThreadPool>> {
    POOL.lock().map(|p| p.clone()).unwrap_or(None)
}

/// Sets the number of threads anaglyph's compute calls use (`None` or 0: one per core).
/// Calls already running keep their pool.
#[pyfunction]
#[pyo3(signature = (n=None))]
pub fn set_num_threads(n: Option<usize>) -> PyResult<()> {
    let pool = match n {
        None | Some(0) => None,
        Some(n) => Some(Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .thread_name(|i| format!("anaglyph-{i}"))
                .build()
                .map_err(|e| internal(format!("cannot start {n} threads: {e}")))?,
        )),
    };
    *POOL
        .lock()
        .map_err(|_| internal("thread pool lock poisoned".into()))? = pool;
    Ok(())
}

/// The number of threads compute calls use.
#[pyfunction]
pub fn get_num_threads() -> usize {
    pool().map_or_else(rayon::current_num_threads, |p| p.current_num_threads())
}

/// The message of a caught panic.
fn panic_message(payload: Box<dyn std::any::Any + Send>) -> String {
    let text = payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into());
    format!("internal error in anaglyph (please report it): {text}")
}

/// Runs `work` without the GIL on the chosen pool; a core error becomes its exception and
/// a panic `InternalError`.
pub fn run<T, F>(py: Python<'_>, work: F) -> PyResult<T>
where
    T: Send,
    F: FnOnce() -> anaglyph_core::Result<T> + Send,
{
    run_cancellable(py, None, work)
}

/// [`run`], setting `cancel` when Python raises from a signal handler (Ctrl-C) while the
/// work runs; that exception is raised when the work returns.
pub fn run_cancellable<T, F>(py: Python<'_>, cancel: Option<&AtomicBool>, work: F) -> PyResult<T>
where
    T: Send,
    F: FnOnce() -> anaglyph_core::Result<T> + Send,
{
    let pool = pool();
    let (outcome, interrupt) = py.detach(move || {
        std::thread::scope(|scope| {
            let (sender, receiver) = mpsc::channel();
            scope.spawn(move || {
                let outcome = catch_unwind(AssertUnwindSafe(move || match pool {
                    Some(pool) => pool.install(work),
                    None => work(),
                }));
                // The receiver waits until this arrives.
                let _ = sender.send(outcome);
            });
            let mut interrupt: Option<PyErr> = None;
            loop {
                match receiver.recv_timeout(SIGNAL_CHECK_INTERVAL) {
                    Ok(outcome) => return (Some(outcome), interrupt),
                    Err(mpsc::RecvTimeoutError::Timeout) if interrupt.is_none() => {
                        if let Err(e) = Python::attach(|py| py.check_signals()) {
                            if let Some(flag) = cancel {
                                flag.store(true, Ordering::Relaxed);
                            }
                            interrupt = Some(e);
                        }
                    }
                    Err(mpsc::RecvTimeoutError::Timeout) => {}
                    Err(mpsc::RecvTimeoutError::Disconnected) => return (None, interrupt),
                }
            }
        })
    });
    if let Some(e) = interrupt {
        return Err(e);
    }
    match outcome {
        Some(Ok(result)) => result.map_err(to_py),
        Some(Err(payload)) => Err(internal(panic_message(payload))),
        None => Err(internal("the compute thread ended without a result".into())),
    }
}

/// Panics inside a compute call, to test that a panic reaches Python as `InternalError`.
#[pyfunction]
pub fn _panic_for_tests(py: Python<'_>) -> PyResult<()> {
    run(py, || -> anaglyph_core::Result<()> {
        panic!("deliberate panic for the binding's tests")
    })
}
