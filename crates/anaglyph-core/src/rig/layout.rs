//! Where the cameras of a rig sit. Either a grid (the rig's `rows`, `cols` and
//! `baseline_mm`, each camera's `row` and `col`) or free positions in the array's plane
//! (each camera's `position_mm = [x, y]`, x right and y down seen from behind the array:
//! hexagons, crosses, irregular layouts), with an optional `name` per camera and one
//! camera marked `reference = true`, the camera the array is calibrated to.
//!
//! In: the rig file. Out: every camera's name, position and whether it is the reference,
//! in rig order (a grid row-major, free positions in file order), checked: a complete grid
//! or distinct positions, unique names usable as file names, at most one reference, and
//! no camera far from every other. Disparities are measured per [`disparity_baseline_mm`]:
//! a grid's horizontal baseline, or a free layout's shortest distance between two cameras.

use super::{RigFile, MAX_RIG_SIDE};
use crate::{Error, Result};

/// Most cameras of a rig with free positions.
pub const MAX_FREE_CAMERAS: usize = 256;
/// A camera whose nearest neighbour is farther than this many times the array's shortest
/// baseline shares too little of the scene with the others to be registered.
pub const MAX_NEIGHBOUR_SPACING: f64 = 3.0;
/// Two positions closer than this (mm) are the same position.
const SAME_POSITION_MM: f64 = 1e-3;
/// Largest |x| or |y| of a position, mm.
const MAX_POSITION_MM: f64 = 1e6;

/// One camera's place in the array.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    /// The camera's name: its capture files are `<name>.png` (or .tif/.tiff, .npy), its
    /// outputs `<name>.hdr`; `r<row>c<col>` on a grid unless named.
    pub name: String,
    /// Optical centre in the array's plane, mm: x right, y down, seen from behind.
    pub position_mm: [f64; 2],
    /// Index into the rig file's `camera` entries.
    pub entry: usize,
}

/// The cameras of `file` in rig order, checked (see the module docs).
pub(super) fn place_cameras(file: &RigFile) -> Result<Vec<Placement>> {
    let rig = format!("rig '{}'", file.name);
    let on_grid = file
        .cameras
        .iter()
        .filter(|c| c.row.is_some() || c.col.is_some())
        .count();
    let free = file
        .cameras
        .iter()
        .filter(|c| c.position_mm.is_some())
        .count();
    let placements = match (on_grid, free) {
        (_, 0) => grid_placements(file, &rig)?,
        (0, _) => free_placements(file, &rig)?,
        _ => {
            return Err(Error::rig_layout(
                &rig,
                format!("{on_grid} cameras with row/col and {free} with position_mm"),
                "row and col for every camera (a grid) or position_mm for every camera",
            ))
        }
    };
    check_names(&placements, &rig)?;
    check_reference(file, &placements, &rig)?;
    Ok(placements)
}

/// The rig order's index of the camera marked `reference = true`, else the first camera.
pub(super) fn reference_index(file: &RigFile, placements: &[Placement]) -> usize {
    placements
        .iter()
        .position(|p| file.cameras[p.entry].reference)
        .unwrap_or(0)
}

/// The distance disparities are measured per, mm: a grid's horizontal baseline, or the
/// shortest distance between two cameras of a free layout (1 mm for a single camera).
pub fn disparity_baseline_mm(file: &RigFile, placements: &[Placement]) -> f64 {
    match file.baseline_mm {
        Some(b) => b.horizontal,
        None => shortest_distance(placements).unwrap_or(1.0),
    }
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The shortest distance between two cameras; None for fewer than two.
fn shortest_distance(placements: &[Placement]) -> Option<f64> {
    let mut shortest: Option<f64> = None;
    for (i, a) in placements.iter().enumerate() {
        for b in &placements[i + 1..] {
            let d = distance(a.position_mm, b.position_mm);
            shortest = Some(shortest.map_or(d, |s| s.min(d)));
        }
    }
    shortest
}

/// A complete grid without duplicates, row-major.
fn grid_placements(file: &RigFile, rig: &str) -> Result<Vec<Placement>> {
    let (Some(rows), Some(cols), Some(b)) = (file.rows, file.cols, file.baseline_mm) else {
        return Err(Error::rig_layout(
            rig,
            "cameras on a grid (row/col) without the rig's rows, cols and baseline_mm",
            "rows, cols and baseline_mm for a grid, or position_mm for every camera",
        ));
    };
    if rows == 0 || cols == 0 || rows > MAX_RIG_SIDE || cols > MAX_RIG_SIDE {
        return Err(Error::rig_layout(
            rig,
            format!("{rows} x {cols} cameras"),
            format!("1 to {MAX_RIG_SIDE} per side"),
        ));
    }
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !(positive(b.horizontal) && positive(b.vertical)) {
        return Err(Error::rig_layout(
            rig,
            format!("baseline {} x {} mm", b.horizontal, b.vertical),
            "positive, finite baselines",
        ));
    }
    let mut at: Vec<Option<usize>> = vec![None; rows * cols];
    for (entry, cam) in file.cameras.iter().enumerate() {
        let (Some(row), Some(col)) = (cam.row, cam.col) else {
            return Err(Error::rig_layout(
                rig,
                format!("camera {} with only one of row and col", entry + 1),
                "row and col for every camera of a grid",
            ));
        };
        if row >= rows || col >= cols {
            return Err(Error::rig_layout(
                rig,
                format!("a camera at row {row} col {col}"),
                format!("cameras inside the {rows} x {cols} grid"),
            ));
        }
        if at[row * cols + col].replace(entry).is_some() {
            return Err(Error::rig_layout(
                rig,
                format!("two cameras at row {row} col {col}"),
                "one camera per grid position",
            ));
        }
    }
    at.iter()
        .enumerate()
        .map(|(i, entry)| {
            let (row, col) = (i / cols, i % cols);
            let entry = entry.ok_or_else(|| {
                Error::rig_layout(
                    rig,
                    format!("no camera at row {row} col {col}"),
                    "one camera per grid position",
                )
            })?;
            Ok(Placement {
                name: file.cameras[entry]
                    .name
                    .clone()
                    .unwrap_or_else(|| grid_name(row, col)),
                position_mm: [col as f64 * b.horizontal, row as f64 * b.vertical],
                entry,
            })
        })
        .collect()
}

/// The name of the camera at (row, col) of a grid that does not name it.
pub fn grid_name(row: usize, col: usize) -> String {
    format!("r{row}c{col}")
}

/// Free positions, in file order: finite, distinct, none far from every other.
fn free_placements(file: &RigFile, rig: &str) -> Result<Vec<Placement>> {
    if file.rows.is_some() || file.cols.is_some() || file.baseline_mm.is_some() {
        return Err(Error::rig_layout(
            rig,
            "rows, cols or baseline_mm with cameras given by position_mm",
            "the grid keys only for cameras given by row and col",
        ));
    }
    if file.cameras.len() > MAX_FREE_CAMERAS {
        return Err(Error::rig_layout(
            rig,
            format!("{} cameras", file.cameras.len()),
            format!("at most {MAX_FREE_CAMERAS}"),
        ));
    }
    let placements: Vec<Placement> = file
        .cameras
        .iter()
        .enumerate()
        .map(|(entry, cam)| Placement {
            name: cam.name.clone().unwrap_or_else(|| format!("cam{entry}")),
            position_mm: cam.position_mm.unwrap_or([f64::NAN; 2]),
            entry,
        })
        .collect();
    for p in &placements {
        let [x, y] = p.position_mm;
        if !(x.abs() <= MAX_POSITION_MM && y.abs() <= MAX_POSITION_MM) {
            return Err(Error::rig_layout(
                format!("{rig}: camera {}", p.name),
                format!("position_mm = [{x}, {y}]"),
                format!("finite coordinates within ±{MAX_POSITION_MM} mm"),
            ));
        }
    }
    check_spacing(&placements, rig)?;
    Ok(placements)
}

/// No two cameras at one position, and every camera within [`MAX_NEIGHBOUR_SPACING`]
/// shortest baselines of another.
fn check_spacing(placements: &[Placement], rig: &str) -> Result<()> {
    let Some(shortest) = shortest_distance(placements) else {
        return Ok(());
    };
    for (i, a) in placements.iter().enumerate() {
        let mut nearest = f64::INFINITY;
        for b in placements
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, b)| b)
        {
            let d = distance(a.position_mm, b.position_mm);
            if d < SAME_POSITION_MM {
                return Err(Error::rig_layout(
                    rig,
                    format!(
                        "cameras {} at [{}, {}] mm and {} at [{}, {}] mm, {d} mm apart",
                        a.name,
                        a.position_mm[0],
                        a.position_mm[1],
                        b.name,
                        b.position_mm[0],
                        b.position_mm[1]
                    ),
                    format!(
                        "one camera per position (positions closer than {SAME_POSITION_MM} mm \
                         are one)"
                    ),
                ));
            }
            nearest = nearest.min(d);
        }
        if nearest > MAX_NEIGHBOUR_SPACING * shortest {
            return Err(Error::rig_layout(
                format!("{rig}: camera {}", a.name),
                format!(
                    "its nearest neighbour {nearest:.1} mm away, {:.1} times the array's \
                     shortest baseline of {shortest:.1} mm",
                    nearest / shortest
                ),
                format!(
                    "a neighbour within {MAX_NEIGHBOUR_SPACING} shortest baselines, so that \
                     it shares enough of the scene to be registered"
                ),
            ));
        }
    }
    Ok(())
}

/// Names are unique and usable as file names (letters, digits, `_`, `-`, `.`; not
/// starting with a dot).
fn check_names(placements: &[Placement], rig: &str) -> Result<()> {
    for (i, p) in placements.iter().enumerate() {
        let usable = !p.name.is_empty()
            && p.name.len() <= 64
            && !p.name.starts_with('.')
            && p.name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
        if !usable {
            return Err(Error::rig_layout(
                rig,
                format!("a camera named '{}'", p.name),
                "names of 1 to 64 letters, digits, '_', '-' or '.', not starting with '.'",
            ));
        }
        if p.name.eq_ignore_ascii_case("all") {
            return Err(Error::rig_layout(
                rig,
                "a camera named 'all'",
                "another name ('all' is what --views takes for every view)",
            ));
        }
        if placements[..i].iter().any(|q| q.name == p.name) {
            return Err(Error::rig_layout(
                rig,
                format!("two cameras named '{}'", p.name),
                "a unique name per camera",
            ));
        }
    }
    Ok(())
}

/// At most one camera is marked `reference = true`.
fn check_reference(file: &RigFile, placements: &[Placement], rig: &str) -> Result<()> {
    let marked: Vec<&str> = placements
        .iter()
        .filter(|p| file.cameras[p.entry].reference)
        .map(|p| p.name.as_str())
        .collect();
    if marked.len() > 1 {
        return Err(Error::rig_layout(
            rig,
            format!("{} reference cameras ({})", marked.len(), marked.join(", ")),
            "at most one camera with reference = true",
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::Rig;

    /// A hexagonal rig of 7 narrow-band monochrome cameras, 40 mm apart, `extra` appended
    /// to the last camera.
    fn hexagon(extra: &str) -> String {
        let mut text = String::from(
            "name = 'hex'\nfocal_length_px = 800.0\nsensor = 'builtin:canon_eos_5d_mark_ii'\n",
        );
        let s = 40.0 * 3f64.sqrt() / 2.0;
        let positions = [
            (0.0, 0.0),
            (40.0, 0.0),
            (20.0, s),
            (-20.0, s),
            (-40.0, 0.0),
            (-20.0, -s),
            (20.0, -s),
        ];
        for (k, (x, y)) in positions.iter().enumerate() {
            text += &format!(
                "[[camera]]\nname = 'nb{}'\nposition_mm = [{x}, {y}]\nfilter = 'gaussian:{}:30'\n",
                k,
                450 + 30 * k
            );
        }
        text + extra
    }

    fn load(text: &str) -> crate::Result<Rig> {
        Rig::from_file(RigFile::from_toml_str(text, "t.toml")?, ".".into())
    }

    #[test]
    fn a_hexagonal_rig_keeps_file_order_names_and_its_reference() {
        let rig = load(&hexagon("reference = true\n")).unwrap();
        assert_eq!(rig.cameras.len(), 7);
        assert_eq!(rig.cameras[3].name, "nb3");
        assert_eq!(rig.cameras[1].position_mm, [40.0, 0.0]);
        assert_eq!(rig.reference, 6);
        assert!((rig.disparity_baseline_mm - 40.0).abs() < 1e-9);
        let without = load(&hexagon("")).unwrap();
        assert_eq!(without.reference, 0);
        // The grid stays a shorthand: the paper rig is named and placed as before.
        let grid = Rig::from_file(
            Rig::paper_rig_file(&crate::rig::PAPER_RIG_FILTERS),
            ".".into(),
        )
        .unwrap();
        assert_eq!(grid.cameras[6].name, "r1c2");
        assert_eq!(grid.cameras[6].position_mm, [60.0, 50.0]);
    }

    #[test]
    fn broken_layouts_are_clear_errors() {
        let error = |text: &str| load(text).unwrap_err().to_string();
        let two = hexagon("reference = true\n").replacen(
            "name = 'nb0'\n",
            "name = 'nb0'\nreference = true\n",
            1,
        );
        let e = error(&two);
        assert!(e.contains("2 reference cameras (nb0, nb6)"), "{e}");
        let same = hexagon("").replace("[40, 0]", "[0, 0]");
        let e = error(&same);
        assert!(
            e.contains("cameras nb0 at [0, 0] mm and nb1 at [0, 0] mm, 0 mm apart"),
            "{e}"
        );
        // Nearly the same: the tolerance is named.
        let near = hexagon("").replace("[40, 0]", "[0.0004, 0]");
        let e = error(&near);
        assert!(
            e.contains("nb1 at [0.0004, 0] mm, 0.0004 mm apart")
                && e.contains("positions closer than 0.001 mm are one"),
            "{e}"
        );
        let far = hexagon("").replace("[40, 0]", "[400, 0]");
        let e = error(&far);
        assert!(
            e.contains("camera nb1") && e.contains("nearest neighbour 381.6 mm away"),
            "{e}"
        );
        let e = error(&hexagon("").replace("name = 'nb2'", "name = 'nb1'"));
        assert!(e.contains("two cameras named 'nb1'"), "{e}");
        let e = error(&hexagon("").replace("name = 'nb2'", "name = '../x'"));
        assert!(e.contains("a camera named '../x'"), "{e}");
        let e = error(&hexagon("row = 0\ncol = 0\n"));
        assert!(
            e.contains("1 cameras with row/col and 7 with position_mm"),
            "{e}"
        );
        let e = error(&hexagon("").replacen("[[camera]]", "rows = 1\n[[camera]]", 1));
        assert!(
            e.contains("rows, cols or baseline_mm with cameras given by position_mm"),
            "{e}"
        );
        let e = error(&hexagon("").replace("position_mm = [40, 0]", "position_mm = [nan, 0]"));
        assert!(
            e.contains("camera nb1") && e.contains("finite coordinates"),
            "{e}"
        );
    }
}
