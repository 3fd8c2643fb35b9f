//! The one error type of the core library. Every message carries the value that was
//! found and the value that was expected, so that a user can fix the input without
//! reading the code.

use std::path::PathBuf;

/// Errors of the spectral core, one variant per cause. Each carries what was found and
/// what was expected (or what is available), so that a caller can match the cause and a
/// user can fix the input without reading the code.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    #[error("{context}: line {line}: {message}")]
    Parse {
        context: String,
        line: usize,
        message: String,
    },

    #[error("{}: {field} is {found} (expected {expected})", file.display())]
    BadField {
        file: PathBuf,
        field: String,
        found: String,
        expected: String,
    },

    #[error("{}: unsupported {what} {found} (supported: {supported})", file.display())]
    UnsupportedFormat {
        file: PathBuf,
        what: String,
        found: String,
        supported: String,
    },

    #[error("{}: {found} bytes (expected {expected}; a partial or stale file?)", path.display())]
    FileSize {
        path: PathBuf,
        found: u64,
        expected: u64,
    },

    #[error("{}: missing ({what})", path.display())]
    MissingFile { path: PathBuf, what: String },

    #[error("{what} is {value} (expected a finite number)")]
    NonFinite { what: String, value: f64 },

    #[error("no {what} '{name}' (available: {available})")]
    NotFound {
        what: String,
        name: String,
        available: String,
    },

    #[error("{what}: {found} (expected {expected})")]
    Mismatch {
        what: String,
        found: String,
        expected: String,
    },

    #[error("{what} cannot be used: {why}")]
    Unusable { what: String, why: String },

    #[error("{}: cannot decode: {message}", file.display())]
    Decode { file: PathBuf, message: String },

    #[error("writing {what}: {message}")]
    Output { what: String, message: String },

    #[error(
        "curve '{name}' covers {have_start} to {have_end} nm but {need_start} to {need_end} nm is needed"
    )]
    CurveNotCovering {
        name: String,
        have_start: f64,
        have_end: f64,
        need_start: f64,
        need_end: f64,
    },

    #[error("shape mismatch in {op}: got {got:?}, expected {expected:?}")]
    Shape {
        op: String,
        got: Vec<usize>,
        expected: Vec<usize>,
    },

    #[error("{op}: {what} is {size} (limit {limit})")]
    TooLarge {
        op: String,
        what: String,
        size: u64,
        limit: u64,
    },

    #[error(
        "the regularised normal matrix C^T C + lambda D^T D is singular (lambda = {lambda}, \
         {rows} measurement rows, {cols} unknowns); use lambda > 0 or more measurements"
    )]
    SingularNormalMatrix {
        lambda: f64,
        rows: usize,
        cols: usize,
    },

    #[error("{setting} is {value} (expected {expected})")]
    OutOfRange {
        setting: String,
        value: f64,
        expected: String,
    },

    #[error("the {stage} stage needs {needs}: {why}")]
    StageDependency {
        stage: &'static str,
        needs: &'static str,
        why: &'static str,
    },

    #[error("linear algebra failure in {op}: {message}")]
    LinearAlgebra { op: String, message: String },

    #[error("{op} did not converge in {iterations} iterations")]
    NoConvergence { op: String, iterations: usize },
}

/// Result alias of the core library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// The cause's name, stable across releases: what a caller (or a binding that maps
    /// causes to exception types) matches on without parsing the message.
    pub fn kind(&self) -> &'static str {
        match self {
            Error::Io { .. } => "Io",
            Error::Parse { .. } => "Parse",
            Error::BadField { .. } => "BadField",
            Error::UnsupportedFormat { .. } => "UnsupportedFormat",
            Error::FileSize { .. } => "FileSize",
            Error::MissingFile { .. } => "MissingFile",
            Error::NonFinite { .. } => "NonFinite",
            Error::NotFound { .. } => "NotFound",
            Error::Mismatch { .. } => "Mismatch",
            Error::Unusable { .. } => "Unusable",
            Error::Decode { .. } => "Decode",
            Error::Output { .. } => "Output",
            Error::CurveNotCovering { .. } => "CurveNotCovering",
            Error::Shape { .. } => "Shape",
            Error::TooLarge { .. } => "TooLarge",
            Error::SingularNormalMatrix { .. } => "SingularNormalMatrix",
            Error::OutOfRange { .. } => "OutOfRange",
            Error::StageDependency { .. } => "StageDependency",
            Error::LinearAlgebra { .. } => "LinearAlgebra",
            Error::NoConvergence { .. } => "NoConvergence",
        }
    }

    pub(crate) fn decode(file: impl Into<PathBuf>, message: impl ToString) -> Self {
        Error::Decode {
            file: file.into(),
            message: message.to_string(),
        }
    }

    pub(crate) fn out_of_range(
        setting: impl Into<String>,
        value: f64,
        expected: impl Into<String>,
    ) -> Self {
        Error::OutOfRange {
            setting: setting.into(),
            value,
            expected: expected.into(),
        }
    }

    pub(crate) fn bad_field(
        file: impl Into<PathBuf>,
        field: impl Into<String>,
        found: impl ToString,
        expected: impl Into<String>,
    ) -> Self {
        Error::BadField {
            file: file.into(),
            field: field.into(),
            found: found.to_string(),
            expected: expected.into(),
        }
    }

    pub(crate) fn mismatch(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::Mismatch {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    pub(crate) fn unusable(what: impl Into<String>, why: impl Into<String>) -> Self {
        Error::Unusable {
            what: what.into(),
            why: why.into(),
        }
    }

    pub(crate) fn output(what: impl Into<String>, message: impl ToString) -> Self {
        Error::Output {
            what: what.into(),
            message: message.to_string(),
        }
    }

    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}
