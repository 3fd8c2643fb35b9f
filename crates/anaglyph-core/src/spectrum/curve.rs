//! A sampled spectral curve with one or more named channels (an RGB sensor, a filter,
//! an illuminant, a set of reflectances), read from and written to the CSV layout of
//! `data/`: a header `wavelength_nm,<name>,...` and one row per wavelength, strictly
//! increasing. Parsing checks the size before allocating and rejects NaN/Inf.

use super::{cubic_spline, integrate_linear, linear, Interpolation, SpectralShape};
use crate::{io::write_atomically, Error, Result};
use std::path::Path;

/// Largest CSV file read as a curve (a 0.1 nm table over 300–1100 nm with 200 columns
/// is about 15 MB).
pub const MAX_CSV_BYTES: u64 = 64 << 20;
/// Most channels one curve file may hold.
pub const MAX_CURVE_CHANNELS: usize = 4096;
/// Slack (nm) when checking that a curve covers a requested range: CSV wavelengths
/// written with few decimals must still cover a grid computed in floating point.
const COVERAGE_SLACK_NM: f64 = 1e-6;

/// A curve sampled at strictly increasing wavelengths, one value vector per channel.
#[derive(Debug, Clone, PartialEq)]
pub struct ResponseCurve {
    name: String,
    wavelengths: Vec<f64>,
    channel_names: Vec<String>,
    /// `values[c][i]` is channel `c` at `wavelengths[i]`.
    values: Vec<Vec<f64>>,
}

impl ResponseCurve {
    /// A validated curve from samples.
    pub fn new(
        name: impl Into<String>,
        wavelengths: Vec<f64>,
        channel_names: Vec<String>,
        values: Vec<Vec<f64>>,
    ) -> Result<Self> {
        let curve = ResponseCurve {
            name: name.into(),
            wavelengths,
            channel_names,
            values,
        };
        curve.validate()?;
        Ok(curve)
    }

    /// A single-channel curve sampled on a shape.
    pub fn from_shape(
        name: impl Into<String>,
        shape: &SpectralShape,
        channel: impl Into<String>,
        values: Vec<f64>,
    ) -> Result<Self> {
        Self::new(
            name,
            shape.wavelengths(),
            vec![channel.into()],
            vec![values],
        )
    }

    fn validate(&self) -> Result<()> {
        let ctx = || format!("curve '{}'", self.name);
        if self.wavelengths.len() < 2 {
            return Err(Error::curve(
                ctx(),
                format!("{} samples", self.wavelengths.len()),
                "at least 2",
            ));
        }
        if self.channel_names.is_empty() || self.channel_names.len() != self.values.len() {
            return Err(Error::curve(
                ctx(),
                format!(
                    "{} channel names for {} value columns",
                    self.channel_names.len(),
                    self.values.len()
                ),
                "one name per column, at least one",
            ));
        }
        for w in self.wavelengths.windows(2) {
            if !(w[1] > w[0]) {
                return Err(Error::curve(
                    ctx(),
                    format!("wavelengths {} then {} nm", w[0], w[1]),
                    "strictly increasing wavelengths",
                ));
            }
        }
        if let Some(w) = self
            .wavelengths
            .iter()
            .find(|w| !w.is_finite() || **w <= 0.0)
        {
            return Err(Error::out_of_range(
                format!("{} wavelength", ctx()),
                *w,
                "a positive, finite wavelength in nm",
            ));
        }
        for (c, column) in self.values.iter().enumerate() {
            if column.len() != self.wavelengths.len() {
                return Err(Error::Shape {
                    op: format!(
                        "{}: channel '{}' against its wavelengths",
                        ctx(),
                        self.channel_names[c]
                    ),
                    got: vec![column.len()],
                    expected: vec![self.wavelengths.len()],
                });
            }
            if let Some(i) = column.iter().position(|v| !v.is_finite()) {
                return Err(Error::NonFinite {
                    what: format!(
                        "{}: channel '{}' at {} nm",
                        ctx(),
                        self.channel_names[c],
                        self.wavelengths[i]
                    ),
                    value: column[i],
                });
            }
        }
        Ok(())
    }

    /// Parses the CSV layout `wavelength_nm,<channel>,...`.
    pub fn from_csv_str(name: impl Into<String>, text: &str) -> Result<Self> {
        let name = name.into();
        let parse_err = |line: usize, message: String| Error::Parse {
            context: format!("curve '{name}'"),
            line,
            message,
        };
        // A byte-order mark (spreadsheets write one) is not part of the header.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let (header_line, header) = lines.next().ok_or_else(|| {
            parse_err(
                1,
                "empty file (expected a header 'wavelength_nm,...')".into(),
            )
        })?;
        let mut columns = header.split(',').map(str::trim);
        let first = columns.next().unwrap_or_default();
        if !first.eq_ignore_ascii_case("wavelength_nm") && !first.eq_ignore_ascii_case("wavelength")
        {
            return Err(parse_err(
                header_line,
                format!("first column is '{first}' (expected 'wavelength_nm')"),
            ));
        }
        let channel_names: Vec<String> = columns.map(String::from).collect();
        if channel_names.is_empty() || channel_names.len() > MAX_CURVE_CHANNELS {
            return Err(parse_err(
                header_line,
                format!(
                    "{} value columns (expected 1 to {MAX_CURVE_CHANNELS})",
                    channel_names.len()
                ),
            ));
        }
        let mut wavelengths = Vec::new();
        let mut values = vec![Vec::new(); channel_names.len()];
        for (line_no, line) in lines {
            let mut fields = line.split(',').map(str::trim);
            let parse = |field: Option<&str>, what: &str| -> Result<f64> {
                let field = field.ok_or_else(|| {
                    parse_err(
                        line_no,
                        format!(
                            "missing {what} ({} columns expected)",
                            channel_names.len() + 1
                        ),
                    )
                })?;
                field
                    .parse::<f64>()
                    .map_err(|_| parse_err(line_no, format!("'{field}' in {what} is not a number")))
            };
            wavelengths.push(parse(fields.next(), "wavelength")?);
            for (c, column) in values.iter_mut().enumerate() {
                column.push(parse(
                    fields.next(),
                    &format!("column '{}'", channel_names[c]),
                )?);
            }
            if fields.next().is_some() {
                return Err(parse_err(
                    line_no,
                    format!("more than {} columns", channel_names.len() + 1),
                ));
            }
        }
        Self::new(name, wavelengths, channel_names, values)
    }

    /// Reads a CSV curve file; the curve is named after the file stem.
    pub fn load_csv(path: &Path) -> Result<Self> {
        let size = std::fs::metadata(path)
            .map_err(|e| Error::io(path, e))?
            .len();
        if size > MAX_CSV_BYTES {
            return Err(Error::TooLarge {
                op: format!("reading {}", path.display()),
                what: "file size".into(),
                size,
                limit: MAX_CSV_BYTES,
            });
        }
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string());
        Self::from_csv_str(name, &text).map_err(|e| match e {
            Error::Parse { line, message, .. } => Error::Parse {
                context: path.display().to_string(),
                line,
                message,
            },
            other => other,
        })
    }

    /// The CSV text of this curve (shortest round-trip decimals).
    pub fn to_csv_string(&self) -> String {
        let mut out = String::from("wavelength_nm");
        for c in &self.channel_names {
            out.push(',');
            out.push_str(c);
        }
        out.push('\n');
        for (i, w) in self.wavelengths.iter().enumerate() {
            out.push_str(&format!("{w}"));
            for column in &self.values {
                out.push_str(&format!(",{}", column[i]));
            }
            out.push('\n');
        }
        out
    }

    /// Writes the CSV atomically (temporary file, then rename).
    pub fn save_csv(&self, path: &Path) -> Result<()> {
        write_atomically(path, |w| w.write_all(self.to_csv_string().as_bytes()))
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// The same curve under another name.
    pub fn renamed(mut self, name: impl Into<String>) -> Self {
        self.name = name.into();
        self
    }

    pub fn wavelengths(&self) -> &[f64] {
        &self.wavelengths
    }

    pub fn channel_names(&self) -> &[String] {
        &self.channel_names
    }

    pub fn channel_count(&self) -> usize {
        self.values.len()
    }

    /// Values of channel `c` at [`Self::wavelengths`].
    pub fn channel(&self, c: usize) -> &[f64] {
        &self.values[c]
    }

    /// Index of the channel named `name`.
    pub fn channel_index(&self, name: &str) -> Result<usize> {
        self.channel_names
            .iter()
            .position(|c| c == name)
            .ok_or_else(|| Error::NotFound {
                what: format!("channel of curve '{}'", self.name),
                name: name.to_string(),
                available: self.channel_names.join(", "),
            })
    }

    /// The curve restricted to one channel.
    pub fn select_channel(&self, c: usize) -> ResponseCurve {
        ResponseCurve {
            name: format!("{}:{}", self.name, self.channel_names[c]),
            wavelengths: self.wavelengths.clone(),
            channel_names: vec![self.channel_names[c].clone()],
            values: vec![self.values[c].clone()],
        }
    }

    /// First and last sampled wavelength in nm.
    pub fn domain(&self) -> (f64, f64) {
        (
            self.wavelengths[0],
            self.wavelengths[self.wavelengths.len() - 1],
        )
    }

    /// Error unless `[lo, hi]` lies inside the sampled range.
    pub fn check_covers(&self, lo: f64, hi: f64) -> Result<()> {
        let (a, b) = self.domain();
        if lo < a - COVERAGE_SLACK_NM || hi > b + COVERAGE_SLACK_NM {
            return Err(Error::CurveNotCovering {
                name: self.name.clone(),
                have_start: a,
                have_end: b,
                need_start: lo,
                need_end: hi,
            });
        }
        Ok(())
    }

    /// Channel `c` evaluated at `at` (which must be covered).
    pub fn sample(&self, c: usize, at: &[f64], how: Interpolation) -> Result<Vec<f64>> {
        if at.is_empty() {
            return Ok(Vec::new());
        }
        let lo = at.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = at.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        self.check_covers(lo, hi)?;
        let (a, b) = self.domain();
        let clamped: Vec<f64> = at.iter().map(|t| t.clamp(a, b)).collect();
        Ok(match how {
            Interpolation::Linear => linear(&self.wavelengths, &self.values[c], &clamped),
            Interpolation::CubicSpline => {
                cubic_spline(&self.wavelengths, &self.values[c], &clamped)
            }
        })
    }

    /// All channels resampled onto `shape`.
    pub fn resample(&self, shape: &SpectralShape, how: Interpolation) -> Result<ResponseCurve> {
        let at = shape.wavelengths();
        let values = (0..self.channel_count())
            .map(|c| self.sample(c, &at, how))
            .collect::<Result<Vec<_>>>()?;
        ResponseCurve::new(self.name.clone(), at, self.channel_names.clone(), values)
    }

    /// Exact integral of channel `c`'s piecewise-linear interpolant over `[lo, hi]` nm.
    pub fn integrate(&self, c: usize, lo: f64, hi: f64) -> Result<f64> {
        if !(lo <= hi) {
            return Err(Error::curve(
                format!("curve '{}': integration band", self.name),
                format!("{lo} to {hi} nm"),
                "a band whose start is at most its end",
            ));
        }
        self.check_covers(lo, hi)?;
        let (a, b) = self.domain();
        Ok(integrate_linear(
            &self.wavelengths,
            &self.values[c],
            lo.max(a),
            hi.min(b),
        ))
    }

    /// Largest value over all channels.
    pub fn peak(&self) -> f64 {
        self.values
            .iter()
            .flatten()
            .cloned()
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// Negative samples (interpolation overshoot, measurement noise) set to zero.
    pub fn clamped_non_negative(mut self) -> Self {
        for v in self.values.iter_mut().flatten() {
            *v = v.max(0.0);
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_round_trip_is_bit_exact() {
        let text = "wavelength_nm,r,g\n400,0.1,0.30000000000000004\n410,0.2,0.5\n420,0.25,1e-3\n";
        let curve = ResponseCurve::from_csv_str("t", text).unwrap();
        let again = ResponseCurve::from_csv_str("t", &curve.to_csv_string()).unwrap();
        assert_eq!(curve, again);
        assert_eq!(curve.channel(1)[0], 0.30000000000000004);
    }

    #[test]
    fn bad_csv_is_a_clear_error() {
        let cases = [
            ("", "empty"),
            ("nm,a\n400,1\n410,2\n", "expected 'wavelength_nm'"),
            ("wavelength_nm,a\n400,1\n", "at least 2"),
            ("wavelength_nm,a\n400,1\n400,2\n", "strictly increasing"),
            ("wavelength_nm,a\n410,1\n400,2\n", "strictly increasing"),
            (
                "wavelength_nm,a\n400,1\n410,NaN\n",
                "expected a finite number",
            ),
            (
                "wavelength_nm,a\n400,1\n410,inf\n",
                "expected a finite number",
            ),
            ("wavelength_nm,a,b\n400,1\n410,2,3\n", "missing"),
            ("wavelength_nm,a\n400,1,2\n410,2\n", "more than 2 columns"),
            ("wavelength_nm,a\n400,x\n410,2\n", "not a number"),
        ];
        for (text, needle) in cases {
            let err = ResponseCurve::from_csv_str("bad", text)
                .unwrap_err()
                .to_string();
            assert!(err.contains(needle), "{text:?}: {err}");
        }
        let variant = |text: &str| ResponseCurve::from_csv_str("bad", text).unwrap_err();
        assert!(matches!(
            variant("wavelength_nm,a\n400,1\n410,NaN\n"),
            Error::NonFinite { .. }
        ));
        assert!(matches!(
            variant("wavelength_nm,a\n410,1\n400,2\n"),
            Error::Curve { .. }
        ));
    }

    #[test]
    fn sampling_outside_the_domain_is_an_error_not_zero() {
        let c = ResponseCurve::from_csv_str("f", "wavelength_nm,t\n400,1\n700,1\n").unwrap();
        assert_eq!(
            c.sample(0, &[399.0], Interpolation::Linear)
                .err()
                .map(|e| e.kind()),
            Some("CurveNotCovering")
        );
        assert_eq!(
            c.integrate(0, 390.0, 500.0).err().map(|e| e.kind()),
            Some("CurveNotCovering")
        );
        let err = c
            .resample(
                &SpectralShape::new(380.0, 5.0, 10).unwrap(),
                Interpolation::Linear,
            )
            .unwrap_err();
        assert!(matches!(err, Error::CurveNotCovering { .. }), "{err}");
        assert_eq!(c.integrate(0, 450.0, 460.0).unwrap(), 10.0);
    }
}
