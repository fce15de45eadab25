use crate::CoreError;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A numeric CSV table: a header row and equally long `f64` columns.
///
/// Reading validates every cell and reports the first problem with file, row
/// (1-based line number, the header being line 1) and column.
#[derive(Debug, Clone, PartialEq)]
pub struct CsvTable {
    /// Where the table was read from (for messages).
    pub path: PathBuf,
    /// Column names in file order.
    pub names: Vec<String>,
    /// Column data, `columns[j][i]` = row i of column j.
    pub columns: Vec<Vec<f64>>,
}

impl CsvTable {
    /// Read and validate a CSV file with a header row.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, CoreError> {
        let path = path.as_ref().to_path_buf();
        let file = std::fs::File::open(&path).map_err(|source| CoreError::Io {
            path: path.clone(),
            source,
        })?;
        Self::from_reader(file, path)
    }

    /// Parse CSV text (used by `read`; `path` only names the source in errors).
    pub fn from_reader<R: std::io::Read>(reader: R, path: PathBuf) -> Result<Self, CoreError> {
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(reader);
        let mut records = rdr.records();
        let header = loop {
            match records.next() {
                None => return Err(CoreError::Empty { path }),
                Some(Err(e)) => return Err(csv_err(&path, e)),
                Some(Ok(r)) => {
                    if r.iter().all(|f| f.is_empty()) {
                        continue;
                    }
                    break r;
                }
            }
        };
        let names: Vec<String> = header.iter().map(|s| s.to_string()).collect();
        if let Some(j) = names.iter().position(|n| n.is_empty()) {
            return Err(CoreError::Csv {
                path,
                row: line_of(&header),
                message: format!("header field {} is empty", j + 1),
            });
        }
        for (j, n) in names.iter().enumerate() {
            if n.parse::<f64>().is_ok() {
                return Err(CoreError::Csv {
                    path,
                    row: line_of(&header),
                    message: format!(
                        "header field {} is the number '{n}': the first row must name the columns",
                        j + 1
                    ),
                });
            }
        }
        let mut columns: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
        for rec in records {
            let rec = rec.map_err(|e| csv_err(&path, e))?;
            let row = line_of(&rec);
            if rec.len() == 1 && rec.get(0) == Some("") {
                continue; // blank line
            }
            if rec.len() != names.len() {
                return Err(CoreError::Ragged {
                    path,
                    row,
                    expected: names.len(),
                    found: rec.len(),
                });
            }
            for (j, field) in rec.iter().enumerate() {
                let v: f64 = field.parse().map_err(|_| CoreError::NonNumeric {
                    path: path.clone(),
                    row,
                    column: names[j].clone(),
                    value: field.to_string(),
                })?;
                if !v.is_finite() {
                    return Err(CoreError::NonFinite {
                        path: path.clone(),
                        row,
                        column: names[j].clone(),
                        value: field.to_string(),
                    });
                }
                columns[j].push(v);
            }
        }
        if columns.first().is_none_or(|c| c.is_empty()) {
            return Err(CoreError::Empty { path });
        }
        Ok(Self {
            path,
            names,
            columns,
        })
    }

    /// Number of data rows.
    pub fn n_rows(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }

    /// The column called `name`, or a `MissingColumn` error naming the file.
    pub fn column(&self, name: &str) -> Result<&[f64], CoreError> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|j| self.columns[j].as_slice())
            .ok_or_else(|| CoreError::MissingColumn {
                path: self.path.clone(),
                column: name.to_string(),
                available: self.names.join(","),
            })
    }
}

fn line_of(r: &csv::StringRecord) -> usize {
    r.position().map_or(0, |p| p.line() as usize)
}

fn csv_err(path: &Path, e: csv::Error) -> CoreError {
    let row = e.position().map_or(0, |p| p.line() as usize);
    match e.into_kind() {
        csv::ErrorKind::Io(source) => CoreError::Io {
            path: path.to_path_buf(),
            source,
        },
        csv::ErrorKind::Utf8 { err, .. } => CoreError::Csv {
            path: path.to_path_buf(),
            row,
            message: format!("invalid UTF-8 ({err})"),
        },
        other => CoreError::Csv {
            path: path.to_path_buf(),
            row,
            message: format!("{other:?}"),
        },
    }
}

/// Write `bytes` to `path` atomically: into a temporary file beside it, then
/// renamed over it, so a failure never leaves a half-written file.
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<(), CoreError> {
    let path = path.as_ref();
    let io = |source| CoreError::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| {
        CoreError::InvalidArgument(format!("{}: not a file name", path.display()))
    })?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(e));
    }
    Ok(())
}

/// Write columns with a header as CSV, atomically (see [`write_atomic`]).
/// Values are written with full round-trip precision.
pub fn write_csv_atomic(
    path: impl AsRef<Path>,
    names: &[&str],
    columns: &[&[f64]],
) -> Result<(), CoreError> {
    if names.len() != columns.len() {
        return Err(CoreError::Dimension(format!(
            "{} names for {} columns",
            names.len(),
            columns.len()
        )));
    }
    let n = columns.first().map_or(0, |c| c.len());
    if columns.iter().any(|c| c.len() != n) {
        return Err(CoreError::Dimension("columns of different lengths".into()));
    }
    let mut out = String::with_capacity(n * columns.len() * 16);
    out.push_str(&names.join(","));
    out.push('\n');
    for i in 0..n {
        for (j, c) in columns.iter().enumerate() {
            if j > 0 {
                out.push(',');
            }
            out.push_str(&format!("{}", c[i]));
        }
        out.push('\n');
    }
    write_atomic(path, out.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<CsvTable, CoreError> {
        CsvTable::from_reader(text.as_bytes(), PathBuf::from("x.csv"))
    }

    #[test]
    fn reads_columns() {
        let t = parse("t,u,y\n0,1,2\n1,3,4.5\n").unwrap();
        assert_eq!(t.names, ["t", "u", "y"]);
        assert_eq!(t.column("y").unwrap(), &[2.0, 4.5]);
        assert_eq!(t.n_rows(), 2);
    }

    #[test]
    fn errors_name_file_row_column() {
        let e = parse("u,y\n1,2\n3,abc\n").unwrap_err().to_string();
        assert_eq!(e, "x.csv: row 3, column 'y': 'abc' is not a number");
        let e = parse("u,y\n1,2\n3\n").unwrap_err().to_string();
        assert_eq!(e, "x.csv: row 3 has 1 fields, the header has 2");
        let e = parse("u,y\n1,NaN\n").unwrap_err().to_string();
        assert_eq!(e, "x.csv: row 2, column 'y': value NaN is not finite");
        let e = parse("u,y\n1,inf\n").unwrap_err().to_string();
        assert!(e.contains("not finite"), "{e}");
        let e = parse("").unwrap_err().to_string();
        assert!(e.contains("empty"), "{e}");
        let e = parse("u,y\n").unwrap_err().to_string();
        assert!(e.contains("empty"), "{e}");
        let e = parse("u,y\n1,\n").unwrap_err().to_string();
        assert!(e.contains("column 'y'"), "{e}");
        let t = parse("u,y\n1,2\n").unwrap();
        let e = t.column("z").unwrap_err().to_string();
        assert_eq!(e, "x.csv: no column named 'z' (columns: u,y)");
    }

    #[test]
    fn numeric_header_is_rejected() {
        assert!(parse("1,2\n3,4\n").is_err());
    }

    #[test]
    fn atomic_write_round_trips() {
        let dir = std::env::temp_dir().join(format!("gbcore-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.csv");
        let a = [0.1, 1.0 / 3.0];
        let b = [1e-300, -2.5];
        write_csv_atomic(&p, &["a", "b"], &[&a, &b]).unwrap();
        let t = CsvTable::read(&p).unwrap();
        assert_eq!(t.columns[0], a);
        assert_eq!(t.columns[1], b);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
