//! The one model-spec grammar of `greybox fit --model`:
//!
//! ```text
//! SPEC    = NAME { "+" COMPONENT } [ ":" OPTION { "," OPTION } ]
//! OPTION  = KEY "=" VALUE          (a list VALUE separates items with "/")
//! ```
//!
//! e.g. `linear`, `lmn+preisach+student-t:order=3`,
//! `lmn:weights=tree,splits=oblique,max_leaves=12,dead_time=0`,
//! `state-space+damper:resonances=150/120`.
//!
//! ```
//! use gb_core::ModelSpec;
//! let s: ModelSpec = "lmn+preisach:order=3,dead_time=2/0".parse().unwrap();
//! assert_eq!((s.name.as_str(), s.components.as_slice()), ("lmn", &["preisach".to_string()][..]));
//! let mut o = s.options();
//! assert_eq!(o.usize("order", 2, 1, 30).unwrap(), 3);
//! assert_eq!(o.usize_list("dead_time", 2, 1, 0, 64).unwrap(), [2, 0]);
//! assert!(o.finish(&["order", "dead_time"]).is_ok());
//! ```
use crate::CoreError;
use std::collections::BTreeMap;

/// A parsed model SPEC.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelSpec {
    /// The recipe name.
    pub name: String,
    /// The `+` components, in order.
    pub components: Vec<String>,
    /// The `KEY=VALUE` options, in order.
    pub options: Vec<(String, String)>,
}

fn bad(spec: &str, why: &str) -> CoreError {
    CoreError::InvalidArgument(format!("model spec '{spec}': {why}"))
}

impl std::str::FromStr for ModelSpec {
    type Err = CoreError;
    fn from_str(s: &str) -> Result<Self, CoreError> {
        let (head, opts) = match s.split_once(':') {
            Some((h, o)) => (h, Some(o)),
            None => (s, None),
        };
        let mut parts = head.split('+').map(str::trim);
        let name = parts.next().unwrap_or("").to_string();
        let word = |w: &str| {
            !w.is_empty()
                && w.chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        };
        if !word(&name) {
            return Err(bad(s, "expected NAME[+COMPONENT...][:KEY=VALUE,...]"));
        }
        let components: Vec<String> = parts.map(str::to_string).collect();
        if let Some(c) = components.iter().find(|c| !word(c)) {
            return Err(bad(s, &format!("empty or invalid component '{c}'")));
        }
        let mut options = vec![];
        if let Some(o) = opts {
            for kv in o.split(',') {
                let (k, v) = kv
                    .split_once('=')
                    .ok_or_else(|| bad(s, &format!("option '{kv}' is not KEY=VALUE")))?;
                let (k, v) = (k.trim(), v.trim());
                if !word(k) || v.is_empty() {
                    return Err(bad(s, &format!("option '{kv}' is not KEY=VALUE")));
                }
                if options.iter().any(|(o, _): &(String, String)| o == k) {
                    return Err(bad(s, &format!("option '{k}' given twice")));
                }
                options.push((k.to_string(), v.to_string()));
            }
        }
        Ok(Self {
            name,
            components,
            options,
        })
    }
}

impl std::fmt::Display for ModelSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name)?;
        for c in &self.components {
            write!(f, "+{c}")?;
        }
        for (i, (k, v)) in self.options.iter().enumerate() {
            write!(f, "{}{k}={v}", if i == 0 { ':' } else { ',' })?;
        }
        Ok(())
    }
}

impl ModelSpec {
    /// Whether component `c` is present.
    pub fn has(&self, c: &str) -> bool {
        self.components.iter().any(|x| x == c)
    }

    /// Add an option unless the spec already has it (flags that map to
    /// options).
    pub fn set_default(&mut self, key: &str, value: impl Into<String>) {
        if !self.options.iter().any(|(k, _)| k == key) {
            self.options.push((key.to_string(), value.into()));
        }
    }

    /// The raw value of option `key`, if given.
    pub fn option(&self, key: &str) -> Option<&str> {
        self.options
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Typed access to the options, which records what was read.
    pub fn options(&self) -> Options {
        Options {
            spec: self.to_string(),
            values: self.options.iter().cloned().collect(),
            read: vec![],
        }
    }
}

/// The options of a spec with typed getters; [`finish`](Self::finish)
/// refuses keys no getter asked for.
#[derive(Debug, Clone)]
pub struct Options {
    spec: String,
    values: BTreeMap<String, String>,
    read: Vec<String>,
}

impl Options {
    fn raw(&mut self, key: &str) -> Option<String> {
        self.read.push(key.to_string());
        self.values.get(key).cloned()
    }

    fn err(&self, key: &str, v: &str, want: &str) -> CoreError {
        bad(&self.spec, &format!("{key}={v}: {want}"))
    }

    /// Whether `key` was given.
    pub fn given(&self, key: &str) -> bool {
        self.values.contains_key(key)
    }

    /// A whole number in `lo..=hi` (`default` when absent).
    pub fn usize(
        &mut self,
        key: &str,
        default: usize,
        lo: usize,
        hi: usize,
    ) -> Result<usize, CoreError> {
        match self.raw(key) {
            None => Ok(default),
            Some(v) => v
                .parse::<usize>()
                .ok()
                .filter(|n| (lo..=hi).contains(n))
                .ok_or_else(|| self.err(key, &v, &format!("a whole number in {lo}..={hi}"))),
        }
    }

    /// An optional number in `lo..=hi`.
    pub fn f64_opt(&mut self, key: &str, lo: f64, hi: f64) -> Result<Option<f64>, CoreError> {
        match self.raw(key) {
            None => Ok(None),
            Some(v) => v
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && (lo..=hi).contains(x))
                .map(Some)
                .ok_or_else(|| self.err(key, &v, &format!("a number in [{lo}, {hi}]"))),
        }
    }

    /// One of `choices` (`default` when absent).
    pub fn choice(
        &mut self,
        key: &str,
        default: &'static str,
        choices: &[&'static str],
    ) -> Result<&'static str, CoreError> {
        match self.raw(key) {
            None => Ok(default),
            Some(v) => choices
                .iter()
                .find(|c| **c == v)
                .copied()
                .ok_or_else(|| self.err(key, &v, &format!("one of {}", choices.join(", ")))),
        }
    }

    /// `true`/`false`/`yes`/`no`/`1`/`0` (`default` when absent).
    pub fn flag(&mut self, key: &str, default: bool) -> Result<bool, CoreError> {
        match self.raw(key).as_deref() {
            None => Ok(default),
            Some("true" | "yes" | "1") => Ok(true),
            Some("false" | "no" | "0") => Ok(false),
            Some(v) => Err(self.err(key, v, "true or false")),
        }
    }

    /// A list of whole numbers in `lo..=hi`: one value for all `n` items or
    /// one per item (`default` for all when absent).
    pub fn usize_list(
        &mut self,
        key: &str,
        n: usize,
        default: usize,
        lo: usize,
        hi: usize,
    ) -> Result<Vec<usize>, CoreError> {
        let Some(v) = self.raw(key) else {
            return Ok(vec![default; n]);
        };
        self.parse_usize_list(key, &v, n, lo, hi)
    }

    /// Alternatives of [`usize_list`](Self::usize_list) separated by `|`
    /// (`delay=1|0|2`: try 1, 0 and 2); the first is the main one. One
    /// list (`default` for all) when absent.
    pub fn usize_list_choices(
        &mut self,
        key: &str,
        n: usize,
        default: usize,
        lo: usize,
        hi: usize,
    ) -> Result<Vec<Vec<usize>>, CoreError> {
        let Some(v) = self.raw(key) else {
            return Ok(vec![vec![default; n]]);
        };
        v.split('|')
            .map(|alt| self.parse_usize_list(key, alt, n, lo, hi))
            .collect()
    }

    fn parse_usize_list(
        &self,
        key: &str,
        v: &str,
        n: usize,
        lo: usize,
        hi: usize,
    ) -> Result<Vec<usize>, CoreError> {
        let vals: Vec<usize> = v
            .split('/')
            .map(|x| {
                x.trim()
                    .parse::<usize>()
                    .ok()
                    .filter(|k| (lo..=hi).contains(k))
            })
            .collect::<Option<_>>()
            .ok_or_else(|| {
                self.err(
                    key,
                    v,
                    &format!("whole numbers in {lo}..={hi}, separated by /"),
                )
            })?;
        match vals.len() {
            1 => Ok(vec![vals[0]; n]),
            k if k == n => Ok(vals),
            k => Err(self.err(
                key,
                v,
                &format!("{k} values for {n} inputs (give one, or one per input)"),
            )),
        }
    }

    /// A list of positive numbers (empty when absent).
    pub fn f64_list(&mut self, key: &str) -> Result<Vec<f64>, CoreError> {
        let Some(v) = self.raw(key) else {
            return Ok(vec![]);
        };
        v.split('/')
            .map(|x| {
                x.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|f| *f > 0.0 && f.is_finite())
            })
            .collect::<Option<_>>()
            .ok_or_else(|| self.err(key, &v, "positive numbers separated by /"))
    }

    /// Refuse any option that is not in `known` or that no getter read.
    pub fn finish(&self, known: &[&str]) -> Result<(), CoreError> {
        if let Some(k) = self
            .values
            .keys()
            .find(|k| !known.contains(&k.as_str()) || !self.read.contains(k))
        {
            return Err(bad(
                &self.spec,
                &format!(
                    "unknown option '{k}' (options here: {})",
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_display_and_errors() {
        for s in [
            "linear",
            "lmn+preisach+student-t:order=3",
            "state-space+damper:resonances=150/120",
        ] {
            let m: ModelSpec = s.parse().unwrap();
            assert_eq!(m.to_string(), s);
        }
        for bad in [
            "",
            "+x",
            "lmn+",
            "lmn:order",
            "lmn:order=",
            "lmn:a=1,a=2",
            "l mn",
        ] {
            assert!(bad.parse::<ModelSpec>().is_err(), "{bad}");
        }
        let s: ModelSpec = "lmn:order=99,zz=1".parse().unwrap();
        let mut o = s.options();
        let e = o.usize("order", 2, 1, 30).unwrap_err().to_string();
        assert!(e.contains("order=99") && e.contains("1..=30"), "{e}");
        let e = o.finish(&["order"]).unwrap_err().to_string();
        assert!(
            e.contains("unknown option 'zz'") && e.contains("options here: order"),
            "{e}"
        );
        let mut o = "x:l=1/2/3".parse::<ModelSpec>().unwrap().options();
        assert!(o.usize_list("l", 2, 0, 0, 9).is_err());
        let mut o = "x:w=tree".parse::<ModelSpec>().unwrap().options();
        assert_eq!(o.choice("w", "gauss", &["gauss", "tree"]).unwrap(), "tree");
        assert!(o.choice("w", "gauss", &["gauss"]).is_err());
    }

    #[test]
    fn list_alternatives_are_separated_by_a_bar() {
        let mut o = "x:d=1|0/2|3".parse::<ModelSpec>().unwrap().options();
        let d = o.usize_list_choices("d", 2, 1, 0, 9).unwrap();
        assert_eq!(d, vec![vec![1, 1], vec![0, 2], vec![3, 3]]);
        assert_eq!(
            o.usize_list_choices("absent", 2, 1, 0, 9).unwrap(),
            vec![vec![1, 1]]
        );
        for bad in ["x:d=1|", "x:d=1|0/2/3", "x:d=1|99"] {
            let mut o = bad.parse::<ModelSpec>().unwrap().options();
            let e = o
                .usize_list_choices("d", 2, 1, 0, 9)
                .unwrap_err()
                .to_string();
            assert!(e.contains("d="), "{bad}: {e}");
        }
    }
}
