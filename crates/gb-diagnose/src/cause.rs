//! The vocabulary of causes a diagnosis can name.
use serde::{Deserialize, Serialize};

/// What a model's simulation misses. Each cause is answered by the
/// [`Extension`](crate::Extension)s that declare it; adding a cause is a
/// variant here plus its extension file and one line in
/// [`EXTENSIONS`](crate::EXTENSIONS).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum Cause {
    /// A static nonlinearity (the output depends nonlinearly on the
    /// regressors).
    Nonlinearity,
    /// Memory of the direction of motion: a loop between input and output.
    Hysteresis,
    /// Missing dynamics: too low an order, an unmodelled mode.
    Dynamics,
    /// The noise is not what the model assumes (heavy tails).
    Noise,
}

impl Cause {
    /// Every cause, in the order reports list them.
    pub const ALL: [Cause; 4] = [
        Cause::Nonlinearity,
        Cause::Hysteresis,
        Cause::Dynamics,
        Cause::Noise,
    ];

    /// The name used in reports and JSON.
    ///
    /// ```
    /// use gb_diagnose::Cause;
    /// assert_eq!(Cause::Hysteresis.name(), "hysteresis");
    /// assert_eq!(Cause::parse("noise"), Some(Cause::Noise));
    /// ```
    pub fn name(self) -> &'static str {
        match self {
            Cause::Nonlinearity => "nonlinearity",
            Cause::Hysteresis => "hysteresis",
            Cause::Dynamics => "dynamics",
            Cause::Noise => "noise",
        }
    }

    /// The cause named `s`.
    pub fn parse(s: &str) -> Option<Cause> {
        Cause::ALL.into_iter().find(|c| c.name() == s)
    }

    /// Whether the cause is structural (the deterministic part of the model
    /// misses it) rather than about the noise.
    pub fn is_structural(self) -> bool {
        !matches!(self, Cause::Noise)
    }
}

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_serialise_lowercase() {
        for c in Cause::ALL {
            assert_eq!(Cause::parse(c.name()), Some(c));
            assert_eq!(
                serde_json::to_string(&c).unwrap(),
                format!("\"{}\"", c.name())
            );
        }
        assert_eq!(Cause::parse("friction"), None);
    }
}
