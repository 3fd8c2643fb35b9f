//! The core's errors as Python exceptions, one class per cause.
//!
//! `anaglyph.AnaglyphError` is the base; every [`anaglyph_core::Error::kind`] has a
//! subclass `<Kind>Error` (e.g. `ShapeError`, `NotFoundError`) that also derives from the
//! builtin its [`ErrorClass`] names, so that `except ValueError` works as Python users
//! expect. The classes are made at import from the core's [`ERROR_KINDS`], so they cannot
//! drift from it. A Rust panic becomes `InternalError` (a `RuntimeError`), never an abort.

use anaglyph_core::{Error, ErrorClass, ERROR_KINDS};
use pyo3::exceptions::{
    PyArithmeticError, PyException, PyFileNotFoundError, PyKeyboardInterrupt, PyMemoryError,
    PyOSError, PyRuntimeError, PyTypeError, PyValueError,
};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

/// The exception classes, made once per interpreter.
static CLASSES: PyOnceLock<Py<PyDict>> = PyOnceLock::new();

/// The builtin a class of causes also derives from.
fn builtin(py: Python<'_>, class: ErrorClass) -> Bound<'_, PyType> {
    match class {
        ErrorClass::InvalidValue => py.get_type::<PyValueError>(),
        ErrorClass::MissingFile => py.get_type::<PyFileNotFoundError>(),
        ErrorClass::Io => py.get_type::<PyOSError>(),
        ErrorClass::Limit => py.get_type::<PyMemoryError>(),
        ErrorClass::Numerical => py.get_type::<PyArithmeticError>(),
        ErrorClass::Cancelled => py.get_type::<PyKeyboardInterrupt>(),
        // The core's class set may grow; a new class is still an AnaglyphError.
        #[allow(unreachable_patterns)]
        _ => py.get_type::<PyException>(),
    }
}

/// `type(name, bases, {"__module__": "anaglyph", "__doc__": doc})`.
fn new_class<'py>(
    py: Python<'py>,
    name: &str,
    bases: Vec<Bound<'py, PyType>>,
    doc: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let namespace = PyDict::new(py);
    namespace.set_item("__module__", "anaglyph")?;
    namespace.set_item("__doc__", doc)?;
    py.get_type::<PyType>()
        .call1((name, PyTuple::new(py, bases)?, namespace))
}

/// Makes the classes and adds them to `module`.
pub fn register(module: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = module.py();
    let classes = PyDict::new(py);
    let base = new_class(
        py,
        "AnaglyphError",
        vec![py.get_type::<PyException>()],
        "Base class of every error anaglyph raises; the message names the input, what was \
         found and what was expected.",
    )?;
    let base_type = base.cast::<PyType>()?.clone();
    classes.set_item("AnaglyphError", &base)?;
    for (kind, class) in ERROR_KINDS {
        let name = format!("{kind}Error");
        let mut bases = vec![base_type.clone()];
        // KeyboardInterrupt is a BaseException: CancelledError keeps both roots.
        bases.push(builtin(py, class));
        let doc = format!("The core's `{kind}` cause.");
        classes.set_item(&name, new_class(py, &name, bases, &doc)?)?;
    }
    let internal = new_class(
        py,
        "InternalError",
        vec![base_type, py.get_type::<PyRuntimeError>()],
        "A bug in anaglyph (a Rust panic caught at the boundary): please report it.",
    )?;
    classes.set_item("InternalError", internal)?;
    for (name, class) in classes.iter() {
        module.add(name.extract::<String>()?, class)?;
    }
    let _ = CLASSES.set(py, classes.unbind());
    Ok(())
}

/// The class named `name` (made by [`register`]).
fn class<'py>(py: Python<'py>, name: &str) -> Option<Bound<'py, PyType>> {
    let classes = CLASSES.get(py)?.bind(py);
    let class = classes.get_item(name).ok()??;
    class.cast_into::<PyType>().ok()
}

/// The core error as its exception: `<Kind>Error`, except that a file that does not
/// exist is always `MissingFileError` (a `FileNotFoundError`).
pub fn to_py(error: Error) -> PyErr {
    Python::attach(|py| {
        let message = error.to_string();
        let name = match error.class() {
            ErrorClass::MissingFile => "MissingFileError".to_string(),
            _ => format!("{}Error", error.kind()),
        };
        match class(py, &name) {
            Some(class) => PyErr::from_type(class, message),
            None => PyRuntimeError::new_err(message),
        }
    })
}

/// A caught panic as `InternalError`.
pub fn internal(message: String) -> PyErr {
    Python::attach(|py| match class(py, "InternalError") {
        Some(class) => PyErr::from_type(class, message),
        None => PyRuntimeError::new_err(message),
    })
}

/// A `TypeError` for an argument of the wrong type.
pub fn type_error(message: impl Into<String>) -> PyErr {
    PyTypeError::new_err(message.into())
}

/// The core's `Shape` cause for an argument of the wrong shape.
pub fn shape_error(op: impl Into<String>, got: &[usize], expected: &[usize]) -> PyErr {
    to_py(Error::Shape {
        op: op.into(),
        got: got.to_vec(),
        expected: expected.to_vec(),
    })
}

/// Converts core results.
pub trait IntoPyResult<T> {
    fn py(self) -> PyResult<T>;
}

impl<T> IntoPyResult<T> for anaglyph_core::Result<T> {
    fn py(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}
