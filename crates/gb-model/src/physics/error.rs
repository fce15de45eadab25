//! The errors of the physics class: every variant renders as one line that
//! names the model file, the line, the expression and the symbol where
//! there is one.
use std::fmt;

/// Which part of a model definition an error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Item {
    /// The model as a whole.
    Model,
    /// The state of this index (its declaration).
    State(usize),
    /// The equation `ẋᵢ = …` of the state of this index.
    Equation(usize),
    /// The output of this index (`y = g(x, u, θ)`).
    Output(usize),
    /// The parameter of this index.
    Parameter(usize),
}

/// Where an error is: the file and line when the model came from a file,
/// and what (e.g. `equation for 'v'`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The model file, when the model came from one.
    pub file: Option<String>,
    /// The 1-based line in the file.
    pub line: Option<usize>,
    /// The part of the model.
    pub item: Item,
    /// The part in words, e.g. `equation for 'v'`.
    pub what: String,
}

impl Location {
    /// A location without file and line.
    pub fn new(item: Item, what: impl Into<String>) -> Self {
        Self {
            file: None,
            line: None,
            item,
            what: what.into(),
        }
    }
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (&self.file, self.line) {
            (Some(file), Some(line)) => write!(f, "{file}:{line}: {}", self.what),
            (Some(file), None) => write!(f, "{file}: {}", self.what),
            (None, _) => write!(f, "{}", self.what),
        }
    }
}

/// Errors of the physics model class.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PhysicsError {
    /// The model file is not valid TOML or has a field of the wrong type.
    #[error("{file}:{line}: {message}")]
    Toml {
        /// The model file.
        file: String,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// An expression does not parse.
    #[error("{at}: \"{expr}\": {message}")]
    Syntax {
        /// Where.
        at: Location,
        /// The expression.
        expr: String,
        /// The parser's message.
        message: String,
    },
    /// An expression names a symbol that is no state, input or parameter.
    #[error("{at}: \"{expr}\": unknown symbol '{symbol}' ({known})")]
    UnknownSymbol {
        /// Where.
        at: Location,
        /// The expression.
        expr: String,
        /// The unknown name.
        symbol: String,
        /// The known names, in words.
        known: String,
    },
    /// Names, equations and states do not match (a state without an
    /// equation, a name used twice, …).
    #[error("{at}: {message}")]
    Dimension {
        /// Where.
        at: Location,
        /// What does not match.
        message: String,
    },
    /// A value is outside its bounds or not a number.
    #[error("{at}: {message}")]
    Value {
        /// Where.
        at: Location,
        /// What is wrong.
        message: String,
    },
    /// An equation gives NaN or ±∞ at the initial point.
    #[error("{at}: \"{expr}\" is {value} at the initial point ({point})")]
    NonFinite {
        /// Where.
        at: Location,
        /// The expression.
        expr: String,
        /// The value (NaN, inf, -inf).
        value: f64,
        /// The values of the symbols it uses.
        point: String,
    },
    /// The data do not fit the model (columns, sample time, lengths).
    #[error("{0}")]
    Data(String),
    /// The simulation left the finite numbers.
    #[error("the simulation diverged at sample {0} (NaN or infinite state)")]
    Diverged(usize),
    /// A numerical failure (singular matrix, infeasible start).
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// A stored model is corrupt or inconsistent.
    #[error("model file: {0}")]
    Format(String),
    /// From gb-core (I/O, the solver).
    #[error(transparent)]
    Core(#[from] gb_core::CoreError),
}

impl PhysicsError {
    /// The location of the error, if it has one.
    pub fn location_mut(&mut self) -> Option<&mut Location> {
        match self {
            Self::Syntax { at, .. }
            | Self::UnknownSymbol { at, .. }
            | Self::Dimension { at, .. }
            | Self::Value { at, .. }
            | Self::NonFinite { at, .. } => Some(at),
            _ => None,
        }
    }
}

impl From<PhysicsError> for gb_core::CoreError {
    fn from(e: PhysicsError) -> Self {
        match e {
            PhysicsError::Core(c) => c,
            PhysicsError::Format(m) => gb_core::CoreError::ModelFile(m),
            e @ PhysicsError::Diverged(_) => gb_core::CoreError::Unstable(e.to_string()),
            // the messages name the file, line and expression already
            e => gb_core::CoreError::ModelFile(e.to_string()),
        }
    }
}

/// Result alias of the physics class.
pub type PhysicsResult<T> = std::result::Result<T, PhysicsError>;
