//! The one error type of the core library. Every message carries the value that was
//! found and the value that was expected, so that a user can fix the input without
//! reading the code.

use std::path::PathBuf;

/// Errors of the spectral core, one variant per cause. Each carries what was found and
/// what was expected (or what is available), so that a caller can match the cause and a
/// user can fix the input without reading the code.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
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

    /// The rig's cameras (their layout, names or count) cannot make an array.
    #[error("{rig}: {found} (expected {expected})")]
    RigLayout {
        rig: String,
        found: String,
        expected: String,
    },

    /// The captures (or white boards, dark frames) do not match the rig's cameras.
    #[error("{what}: {found} (expected {expected})")]
    Captures {
        what: String,
        found: String,
        expected: String,
    },

    /// A calibration does not fit the cameras or the captures.
    #[error("{what}: {found} (expected {expected})")]
    Calibration {
        what: String,
        found: String,
        expected: String,
    },

    /// An image, map or cube of a size or channel count that does not fit.
    #[error("{what}: {found} (expected {expected})")]
    Raster {
        what: String,
        found: String,
        expected: String,
    },

    /// A disparity search range that is malformed or does not fit the images.
    #[error("{what}: {found} (expected {expected})")]
    DisparityRange {
        what: String,
        found: String,
        expected: String,
    },

    /// A spectral curve, filter reference or sampling that cannot be used.
    #[error("{what}: {found} (expected {expected})")]
    Curve {
        what: String,
        found: String,
        expected: String,
    },

    /// A scene description (objects, materials, shapes) that cannot be rendered.
    #[error("{what}: {found} (expected {expected})")]
    Scene {
        what: String,
        found: String,
        expected: String,
    },

    /// A setting, or a combination of settings, that the operation cannot take.
    #[error("{what}: {found} (expected {expected})")]
    Setting {
        what: String,
        found: String,
        expected: String,
    },

    /// An output path or folder that holds something else.
    #[error("{what}: {found} (expected {expected})")]
    OutputConflict {
        what: String,
        found: String,
        expected: String,
    },

    /// A probe pixel outside the image.
    #[error("probe: pixel ({x}, {y}) (expected a pixel inside the {width}x{height} image)")]
    ProbeOutside {
        x: usize,
        y: usize,
        width: usize,
        height: usize,
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

    #[error("cancelled before {stage}")]
    Cancelled { stage: String },
}

/// The broad class of a cause, for a front end that maps causes onto its own families of
/// errors (the Python package's exceptions derive from `ValueError`, `FileNotFoundError`,
/// `OSError`, `MemoryError` or `ArithmeticError` by it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorClass {
    /// An input (file contents, argument, setting) has a wrong value.
    InvalidValue,
    /// A file that was named does not exist.
    MissingFile,
    /// Reading or writing failed.
    Io,
    /// A size over a limit (memory, pixels, file size).
    Limit,
    /// A numerical method failed on the data.
    Numerical,
    /// The caller asked the run to stop.
    Cancelled,
}

/// Every [`Error::kind`] with its class, in the enum's order.
pub const ERROR_KINDS: [(&str, ErrorClass); 30] = [
    ("Io", ErrorClass::Io),
    ("Parse", ErrorClass::InvalidValue),
    ("BadField", ErrorClass::InvalidValue),
    ("UnsupportedFormat", ErrorClass::InvalidValue),
    ("FileSize", ErrorClass::InvalidValue),
    ("MissingFile", ErrorClass::MissingFile),
    ("NonFinite", ErrorClass::InvalidValue),
    ("NotFound", ErrorClass::InvalidValue),
    ("RigLayout", ErrorClass::InvalidValue),
    ("Captures", ErrorClass::InvalidValue),
    ("Calibration", ErrorClass::InvalidValue),
    ("Raster", ErrorClass::InvalidValue),
    ("DisparityRange", ErrorClass::InvalidValue),
    ("Curve", ErrorClass::InvalidValue),
    ("Scene", ErrorClass::InvalidValue),
    ("Setting", ErrorClass::InvalidValue),
    ("OutputConflict", ErrorClass::InvalidValue),
    ("ProbeOutside", ErrorClass::InvalidValue),
    ("Unusable", ErrorClass::InvalidValue),
    ("Decode", ErrorClass::InvalidValue),
    ("Output", ErrorClass::Io),
    ("CurveNotCovering", ErrorClass::InvalidValue),
    ("Shape", ErrorClass::InvalidValue),
    ("TooLarge", ErrorClass::Limit),
    ("SingularNormalMatrix", ErrorClass::Numerical),
    ("OutOfRange", ErrorClass::InvalidValue),
    ("StageDependency", ErrorClass::InvalidValue),
    ("LinearAlgebra", ErrorClass::Numerical),
    ("NoConvergence", ErrorClass::Numerical),
    ("Cancelled", ErrorClass::Cancelled),
];

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
            Error::RigLayout { .. } => "RigLayout",
            Error::Captures { .. } => "Captures",
            Error::Calibration { .. } => "Calibration",
            Error::Raster { .. } => "Raster",
            Error::DisparityRange { .. } => "DisparityRange",
            Error::Curve { .. } => "Curve",
            Error::Scene { .. } => "Scene",
            Error::Setting { .. } => "Setting",
            Error::OutputConflict { .. } => "OutputConflict",
            Error::ProbeOutside { .. } => "ProbeOutside",
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
            Error::Cancelled { .. } => "Cancelled",
        }
    }

    /// The cause's class ([`ERROR_KINDS`]); an [`Error::Io`] for a file that does not exist
    /// is [`ErrorClass::MissingFile`].
    pub fn class(&self) -> ErrorClass {
        if let Error::Io { source, .. } = self {
            if source.kind() == std::io::ErrorKind::NotFound {
                return ErrorClass::MissingFile;
            }
        }
        let kind = self.kind();
        ERROR_KINDS
            .iter()
            .find(|(k, _)| *k == kind)
            .map_or(ErrorClass::InvalidValue, |(_, class)| *class)
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

    /// An [`Error::RigLayout`]: `rig` was `found` where `expected` was expected.
    pub fn rig_layout(
        rig: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::RigLayout {
            rig: rig.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::Captures`]: `what` was `found` where `expected` was expected.
    pub fn captures(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::Captures {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::Calibration`]: `what` was `found` where `expected` was expected.
    pub fn calibration(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::Calibration {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::Raster`]: `what` was `found` where `expected` was expected.
    pub fn raster(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::Raster {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::DisparityRange`]: `what` was `found` where `expected` was expected.
    pub fn disparity_range(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::DisparityRange {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::Curve`]: `what` was `found` where `expected` was expected.
    pub fn curve(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::Curve {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::Scene`]: `what` was `found` where `expected` was expected.
    pub fn scene(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::Scene {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::Setting`]: `what` was `found` where `expected` was expected.
    pub fn setting(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::Setting {
            what: what.into(),
            found: found.into(),
            expected: expected.into(),
        }
    }

    /// An [`Error::OutputConflict`]: `what` was `found` where `expected` was expected.
    pub fn output_conflict(
        what: impl Into<String>,
        found: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Error::OutputConflict {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// One error of every variant: `variant_index` matches exhaustively, so a new variant
    /// does not compile until it is added here and to [`ERROR_KINDS`].
    fn one_of_each() -> Vec<Error> {
        let s = || String::from("x");
        let p = || PathBuf::from("x");
        vec![
            Error::io(p(), std::io::Error::other("x")),
            Error::Parse {
                context: s(),
                line: 1,
                message: s(),
            },
            Error::bad_field(p(), "x", "x", "x"),
            Error::UnsupportedFormat {
                file: p(),
                what: s(),
                found: s(),
                supported: s(),
            },
            Error::FileSize {
                path: p(),
                found: 1,
                expected: 2,
            },
            Error::MissingFile {
                path: p(),
                what: s(),
            },
            Error::NonFinite {
                what: s(),
                value: f64::NAN,
            },
            Error::NotFound {
                what: s(),
                name: s(),
                available: s(),
            },
            Error::rig_layout("x", "x", "x"),
            Error::captures("x", "x", "x"),
            Error::calibration("x", "x", "x"),
            Error::raster("x", "x", "x"),
            Error::disparity_range("x", "x", "x"),
            Error::curve("x", "x", "x"),
            Error::scene("x", "x", "x"),
            Error::setting("x", "x", "x"),
            Error::output_conflict("x", "x", "x"),
            Error::ProbeOutside {
                x: 1,
                y: 1,
                width: 1,
                height: 1,
            },
            Error::unusable("x", "x"),
            Error::decode(p(), "x"),
            Error::output("x", "x"),
            Error::CurveNotCovering {
                name: s(),
                have_start: 0.0,
                have_end: 1.0,
                need_start: 0.0,
                need_end: 2.0,
            },
            Error::Shape {
                op: s(),
                got: vec![1],
                expected: vec![2],
            },
            Error::TooLarge {
                op: s(),
                what: s(),
                size: 2,
                limit: 1,
            },
            Error::SingularNormalMatrix {
                lambda: 0.0,
                rows: 1,
                cols: 2,
            },
            Error::out_of_range("x", 1.0, "x"),
            Error::StageDependency {
                stage: "x",
                needs: "x",
                why: "x",
            },
            Error::LinearAlgebra {
                op: s(),
                message: s(),
            },
            Error::NoConvergence {
                op: s(),
                iterations: 1,
            },
            Error::Cancelled { stage: s() },
        ]
    }

    fn variant_index(e: &Error) -> usize {
        match e {
            Error::Io { .. } => 0,
            Error::Parse { .. } => 1,
            Error::BadField { .. } => 2,
            Error::UnsupportedFormat { .. } => 3,
            Error::FileSize { .. } => 4,
            Error::MissingFile { .. } => 5,
            Error::NonFinite { .. } => 6,
            Error::NotFound { .. } => 7,
            Error::RigLayout { .. } => 8,
            Error::Captures { .. } => 9,
            Error::Calibration { .. } => 10,
            Error::Raster { .. } => 11,
            Error::DisparityRange { .. } => 12,
            Error::Curve { .. } => 13,
            Error::Scene { .. } => 14,
            Error::Setting { .. } => 15,
            Error::OutputConflict { .. } => 16,
            Error::ProbeOutside { .. } => 17,
            Error::Unusable { .. } => 18,
            Error::Decode { .. } => 19,
            Error::Output { .. } => 20,
            Error::CurveNotCovering { .. } => 21,
            Error::Shape { .. } => 22,
            Error::TooLarge { .. } => 23,
            Error::SingularNormalMatrix { .. } => 24,
            Error::OutOfRange { .. } => 25,
            Error::StageDependency { .. } => 26,
            Error::LinearAlgebra { .. } => 27,
            Error::NoConvergence { .. } => 28,
            Error::Cancelled { .. } => 29,
        }
    }

    #[test]
    fn the_kind_table_lists_every_variant_in_order() {
        let errors = one_of_each();
        assert_eq!(errors.len(), ERROR_KINDS.len());
        for (i, e) in errors.iter().enumerate() {
            assert_eq!(variant_index(e), i, "{e}");
            assert_eq!(e.kind(), ERROR_KINDS[i].0);
            assert_eq!(e.class(), ERROR_KINDS[i].1);
        }
    }
}
