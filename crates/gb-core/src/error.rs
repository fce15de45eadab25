use std::path::PathBuf;

/// Errors of the core crate. Every variant renders as one line that names the
/// file, row and column involved where there is one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CoreError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// File involved.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The file holds no header or no data rows.
    #[error("{path}: file is empty (a header row and at least one data row are needed)")]
    Empty {
        /// File involved.
        path: PathBuf,
    },
    /// A column asked for is not in the header.
    #[error("{path}: no column named '{column}' (columns: {available})")]
    MissingColumn {
        /// File involved.
        path: PathBuf,
        /// Column asked for.
        column: String,
        /// Comma-separated header.
        available: String,
    },
    /// A row has a different number of fields than the header.
    #[error("{path}: row {row} has {found} fields, the header has {expected}")]
    Ragged {
        /// File involved.
        path: PathBuf,
        /// 1-based line number in the file (the header is line 1).
        row: usize,
        /// Fields in the header.
        expected: usize,
        /// Fields in this row.
        found: usize,
    },
    /// A cell is not a number.
    #[error("{path}: row {row}, column '{column}': '{value}' is not a number")]
    NonNumeric {
        /// File involved.
        path: PathBuf,
        /// 1-based line number.
        row: usize,
        /// Column name.
        column: String,
        /// Offending text.
        value: String,
    },
    /// A cell is NaN or infinite.
    #[error("{path}: row {row}, column '{column}': value {value} is not finite")]
    NonFinite {
        /// File involved.
        path: PathBuf,
        /// 1-based line number.
        row: usize,
        /// Column name.
        column: String,
        /// Offending text.
        value: String,
    },
    /// A CSV syntax problem reported by the parser.
    #[error("{path}: row {row}: {message}")]
    Csv {
        /// File involved.
        path: PathBuf,
        /// 1-based line number.
        row: usize,
        /// Parser message.
        message: String,
    },
    /// Fewer samples than the operation needs.
    #[error("{context}: {got} samples, at least {needed} are needed")]
    TooShort {
        /// What was being done.
        context: String,
        /// Samples needed.
        needed: usize,
        /// Samples available.
        got: usize,
    },
    /// A signal that must vary is constant.
    #[error("{context}: signal '{name}' is constant, so it carries no information")]
    Constant {
        /// What was being done.
        context: String,
        /// Signal name.
        name: String,
    },
    /// Signals of different lengths or counts were combined.
    #[error("dimension mismatch: {0}")]
    Dimension(String),
    /// Any other invalid argument.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// The operation is not available for this model class.
    #[error("{0}")]
    Unsupported(String),
    /// A model file cannot be read (the message names the file).
    #[error("{0}")]
    ModelFile(String),
    /// A simulation or fit diverged.
    #[error("unstable: {0}")]
    Unstable(String),
}
