//! OpenCV FileStorage calibration files (the YAML and JSON layouts that `cv::FileStorage`
//! writes, e.g. from `calibrateCamera` or `stereoCalibrate`), read into named numbers and
//! matrices. Rectification turns them into [`super::CameraModel`]s.
//!
//! ```text
//! %YAML:1.0                           {
//! ---                                   "camera_matrix": {
//! image_width: 640                        "type_id": "opencv-matrix",
//! camera_matrix: !!opencv-matrix          "rows": 3, "cols": 3, "dt": "d",
//!    rows: 3                              "data": [ ... ] },
//!    cols: 3                            "image_width": 640
//!    dt: d                            }
//!    data: [ 1.0e+03, 0., 3.195e+02,
//!        0., 1.0e+03, 2.395e+02, 0., 0., 1. ]
//! ```

use crate::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;

/// One entry of a FileStorage file.
#[derive(Debug, Clone, PartialEq)]
pub enum StoredValue {
    Number(f64),
    /// Row-major `rows × cols`.
    Matrix {
        rows: usize,
        cols: usize,
        data: Vec<f64>,
    },
}

/// The top-level entries of a FileStorage file, by name.
pub type FileStorage = BTreeMap<String, StoredValue>;

/// Reads a `.json`, `.yml` or `.yaml` FileStorage file (the layout is told by its first
/// non-blank character, not its name).
pub fn read_file_storage(path: &Path) -> Result<FileStorage> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let context = path.display().to_string();
    match text.trim_start().chars().next() {
        Some('{' | '[') => parse_json(&text, &context),
        Some('<') => Err(Error::UnsupportedFormat {
            file: path.into(),
            what: "FileStorage layout".into(),
            found: "XML".into(),
            supported: "YAML (.yml, .yaml) and JSON (.json)".into(),
        }),
        Some(_) => parse_yaml(&text, &context),
        None => Err(Error::decode(path, "empty calibration file")),
    }
}

/// Parses the JSON layout.
pub fn parse_json(text: &str, context: &str) -> Result<FileStorage> {
    let value: serde_json::Value = serde_json::from_str(text).map_err(|e| Error::Parse {
        context: context.into(),
        line: e.line(),
        message: e.to_string(),
    })?;
    // A bare array of rows is the matrix alone: 3 rows a homography, 2 an affine map.
    if let serde_json::Value::Array(rows) = &value {
        let name = match rows.len() {
            3 => "homography",
            2 => "affine",
            n => {
                return Err(Error::bad_field(
                    context,
                    "the array of rows",
                    format!("{n} rows"),
                    "3 rows of 3 (a homography) or 2 rows of 3 (an affine map)",
                ))
            }
        };
        if !rows
            .iter()
            .all(|r| r.as_array().is_some_and(|r| r.len() == 3))
        {
            return Err(Error::bad_field(
                context,
                "the array of rows",
                value.to_string(),
                "rows of 3 numbers",
            ));
        }
        return Ok(FileStorage::from([(
            name.to_string(),
            rows_matrix(name, rows, context)?,
        )]));
    }
    let object = value.as_object().ok_or_else(|| {
        Error::decode(
            context,
            "expected a JSON object at the top level (or a bare array of the matrix's rows)",
        )
    })?;
    let mut out = FileStorage::new();
    for (name, entry) in object {
        let stored = match entry {
            serde_json::Value::Number(n) => n.as_f64().map(StoredValue::Number),
            serde_json::Value::Object(m)
                if m.get("type_id").and_then(|t| t.as_str()) == Some("opencv-matrix") =>
            {
                let size = |key: &str| {
                    m.get(key)
                        .and_then(|v| v.as_u64())
                        .map(|v| v as usize)
                        .ok_or_else(|| {
                            Error::bad_field(
                                context,
                                format!("matrix '{name}'"),
                                format!("without '{key}'"),
                                "rows, cols and data",
                            )
                        })
                };
                let data = m
                    .get("data")
                    .and_then(|d| d.as_array())
                    .ok_or_else(|| {
                        Error::bad_field(
                            context,
                            format!("matrix '{name}'"),
                            "without data",
                            "rows, cols and data",
                        )
                    })?
                    .iter()
                    .map(|v| {
                        v.as_f64().ok_or_else(|| {
                            Error::bad_field(context, format!("matrix '{name}'"), v, "numbers")
                        })
                    })
                    .collect::<Result<Vec<f64>>>()?;
                Some(matrix(name, size("rows")?, size("cols")?, data, context)?)
            }
            serde_json::Value::Array(values) => array_matrix(name, values, context)?,
            // Strings, lists of views and other nodes are not needed for calibration.
            _ => None,
        };
        if let Some(stored) = stored {
            out.insert(name.clone(), stored);
        }
    }
    Ok(out)
}

/// A matrix given as a plain array: of rows (`[[1, 0, 4], [0, 1, 0], [0, 0, 1]]`) or of
/// numbers (`[k1, k2, p1, p2]`, a 1×n matrix). None for other arrays (lists of strings,
/// of views), which calibration does not need.
fn array_matrix(
    name: &str,
    values: &[serde_json::Value],
    context: &str,
) -> Result<Option<StoredValue>> {
    if values.is_empty() {
        return Ok(None);
    }
    if values.iter().all(|r| r.is_array()) {
        return rows_matrix(name, values, context).map(Some);
    }
    if values.iter().all(|v| v.is_number()) {
        let data = values.iter().filter_map(|v| v.as_f64()).collect::<Vec<_>>();
        return matrix(name, 1, data.len(), data, context).map(Some);
    }
    Ok(None)
}

/// A matrix given as a JSON array of equally long rows of numbers.
fn rows_matrix(name: &str, rows: &[serde_json::Value], context: &str) -> Result<StoredValue> {
    let rows: Vec<&Vec<serde_json::Value>> = rows.iter().filter_map(|r| r.as_array()).collect();
    let cols = rows.first().map_or(0, |r| r.len());
    let mut data = Vec::with_capacity(rows.len() * cols);
    for row in &rows {
        if row.len() != cols {
            return Err(Error::bad_field(
                context,
                format!("matrix '{name}'"),
                format!("rows of {} and {} values", cols, row.len()),
                "rows of equal length",
            ));
        }
        for v in row.iter() {
            data.push(v.as_f64().ok_or_else(|| {
                Error::bad_field(context, format!("matrix '{name}'"), v, "numbers")
            })?);
        }
    }
    matrix(name, rows.len(), cols, data, context)
}

fn matrix(
    name: &str,
    rows: usize,
    cols: usize,
    data: Vec<f64>,
    context: &str,
) -> Result<StoredValue> {
    if data.len() != rows * cols {
        return Err(Error::bad_field(
            context,
            format!("matrix '{name}' ({rows}x{cols})"),
            format!("{} numbers", data.len()),
            format!("{} numbers", rows * cols),
        ));
    }
    if let Some(bad) = data.iter().find(|v| !v.is_finite()) {
        return Err(Error::NonFinite {
            what: format!("{context}: an entry of matrix '{name}'"),
            value: *bad,
        });
    }
    Ok(StoredValue::Matrix { rows, cols, data })
}

/// Parses the YAML layout: top-level `name: number` and `name: !!opencv-matrix` blocks
/// (rows, cols, dt, data, the data list possibly spanning lines). Other nodes are skipped.
pub fn parse_yaml(text: &str, context: &str) -> Result<FileStorage> {
    let mut out = FileStorage::new();
    let lines: Vec<&str> = text.lines().collect();
    let mut i = 0;
    while i < lines.len() {
        let line = strip_comment(lines[i]);
        let number = i + 1;
        i += 1;
        if line.trim().is_empty()
            || line.starts_with('%')
            || line.starts_with("---")
            || line.starts_with("...")
            || line.starts_with([' ', '\t', '-'])
        {
            continue;
        }
        let Some((name, rest)) = line.split_once(':') else {
            return Err(Error::Parse {
                context: context.into(),
                line: number,
                message: format!("expected 'name: value', found '{}'", line.trim()),
            });
        };
        let (name, rest) = (name.trim().trim_matches('"'), rest.trim());
        if rest.starts_with("!!opencv-matrix") || rest.is_empty() {
            // The block: indented `key: value` lines, `data` possibly spanning lines.
            let mut fields: BTreeMap<&str, String> = BTreeMap::new();
            let mut data_line = number;
            while i < lines.len() {
                let inner = strip_comment(lines[i]);
                if !inner.starts_with([' ', '\t']) && !inner.trim().is_empty() {
                    break;
                }
                i += 1;
                let Some((key, value)) = inner.trim().split_once(':') else {
                    continue;
                };
                let key = key.trim();
                let mut value = value.trim().to_string();
                if key == "data" {
                    data_line = i;
                }
                if key == "data" && value.starts_with('[') {
                    while !value.contains(']')
                        && i < lines.len()
                        && lines[i].starts_with([' ', '\t'])
                    {
                        value.push(' ');
                        value.push_str(strip_comment(lines[i]).trim());
                        i += 1;
                    }
                    if !value.contains(']') {
                        return Err(Error::Parse {
                            context: context.into(),
                            line: number,
                            message: format!("matrix '{name}': data list is not closed"),
                        });
                    }
                }
                if let Some(stored) = ["rows", "cols", "dt", "data"].iter().find(|k| **k == key) {
                    fields.insert(stored, value);
                }
            }
            if rest.is_empty() && !fields.contains_key("data") {
                continue; // a nested map that is not a matrix
            }
            let size = |key: &str| -> Result<usize> {
                fields
                    .get(key)
                    .and_then(|v| v.parse().ok())
                    .ok_or_else(|| Error::Parse {
                        context: context.into(),
                        line: number,
                        message: format!("matrix '{name}' has no valid '{key}'"),
                    })
            };
            let (rows, cols) = (size("rows")?, size("cols")?);
            let data = fields
                .get("data")
                .map(|d| parse_number_list(d, name, data_line, context))
                .transpose()?
                .unwrap_or_default();
            out.insert(name.to_string(), matrix(name, rows, cols, data, context)?);
        } else if let Ok(value) = rest.trim_matches('"').parse::<f64>() {
            out.insert(name.to_string(), StoredValue::Number(value));
        } else if rest.starts_with('[') {
            // A flow list on one line: `[k1, k2, p1, p2]` or `[[1, 0, 4], [0, 1, 0], ...]`.
            let Ok(serde_json::Value::Array(values)) = serde_json::from_str(rest) else {
                return Err(Error::Parse {
                    context: context.into(),
                    line: number,
                    message: format!(
                        "'{name}': '{rest}' is not a list of numbers or of rows of numbers"
                    ),
                });
            };
            if let Some(stored) = array_matrix(name, &values, context)? {
                out.insert(name.to_string(), stored);
            }
        }
    }
    Ok(out)
}

fn strip_comment(line: &str) -> &str {
    line.split_once('#').map_or(line, |(before, _)| before)
}

fn parse_number_list(text: &str, name: &str, line: usize, context: &str) -> Result<Vec<f64>> {
    text.trim()
        .trim_start_matches('[')
        .trim_end_matches(']')
        .split([',', ' ', '\t'])
        .filter(|t| !t.is_empty())
        .map(|t| {
            t.parse::<f64>().map_err(|_| Error::Parse {
                context: context.into(),
                line,
                message: format!("matrix '{name}': '{t}' is not a number"),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const YAML: &str = "%YAML:1.0
---
calibration_time: \"Mon 23 Nov 2026\"
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1.0500000000000000e+03, 0., 3.1950000000000000e+02, 0.,
       1.0500000000000000e+03, 2.3950000000000000e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -1.2e-01, 3.0e-02, 0., 0., 0. ] # radial only
avg_reprojection_error: 0.21
";

    #[test]
    fn yaml_and_json_layouts_read_the_same_matrices() {
        let yaml = parse_yaml(YAML, "test.yml").unwrap();
        assert_eq!(yaml["image_width"], StoredValue::Number(640.0));
        let StoredValue::Matrix { rows, cols, data } = &yaml["camera_matrix"] else {
            panic!("not a matrix");
        };
        assert_eq!((*rows, *cols), (3, 3));
        assert_eq!(data[0], 1050.0);
        assert_eq!(data[5], 239.5);
        let json = r#"{ "image_width": 640, "image_height": 480,
            "camera_matrix": { "type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
              "data": [1050.0, 0.0, 319.5, 0.0, 1050.0, 239.5, 0.0, 0.0, 1.0] },
            "distortion_coefficients": { "type_id": "opencv-matrix", "rows": 5, "cols": 1,
              "dt": "d", "data": [-0.12, 0.03, 0.0, 0.0, 0.0] },
            "avg_reprojection_error": 0.21 }"#;
        let json = parse_json(json, "test.json").unwrap();
        assert_eq!(yaml, json);
    }

    #[test]
    fn malformed_files_give_the_line_and_the_reason() {
        let short = YAML.replace("0., 0., 1. ]", "0., 1. ]");
        let err = parse_yaml(&short, "cam.yml").unwrap_err();
        assert!(
            matches!(&err, Error::BadField { found, expected, .. }
                if found == "8 numbers" && expected == "9 numbers"),
            "{err}"
        );
        let xml = tempfile::tempdir().unwrap();
        let path = xml.path().join("cam.xml");
        std::fs::write(&path, "<?xml version=\"1.0\"?>\n<opencv_storage/>").unwrap();
        let err = read_file_storage(&path).unwrap_err();
        assert!(
            matches!(&err, Error::UnsupportedFormat { found, .. } if found == "XML"),
            "{err}"
        );
        let open = YAML.replace("0., 0., 1. ]", "0., 0., 1.");
        let err = parse_yaml(&open, "cam.yml").unwrap_err().to_string();
        assert!(err.contains("not closed"), "{err}");
        let word = YAML.replace("-1.2e-01", "minus");
        let err = parse_yaml(&word, "cam.yml").unwrap_err().to_string();
        assert!(err.contains("line 16") && err.contains("'minus'"), "{err}");
        let err = parse_json("{ \"a\": ", "cam.json").unwrap_err().to_string();
        assert!(err.contains("cam.json: line 1"), "{err}");
    }
}
