//! The layout of an array as registration sees it: every view's name and optical centre in
//! units of the disparity baseline (x right, y down, seen from behind the array), so that
//! a point of view i at disparity d appears in view j at `(x, y) + d · shift(i, j)` along
//! that pair's own baseline direction: rows, columns, diagonals, hexagons and irregular
//! layouts alike.
//!
//! In: a rig (or a grid's size for tests and benches). Out: shifts per unit disparity,
//! each view's neighbours, its nearest view along a row or a column, and which views are
//! inside the array.

use crate::rig::{grid_name, Rig};
use serde::Serialize;

/// Coordinates (in disparity baselines) closer than this are the same row or column.
const SAME_LINE: f64 = 1e-6;

/// Where the views of an array sit (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArrayGeometry {
    /// Per view: its camera's name.
    pub names: Vec<String>,
    /// Per view: its optical centre (x, y) in units of the disparity baseline.
    pub positions: Vec<[f64; 2]>,
}

impl ArrayGeometry {
    /// The rig's cameras, in rig order.
    pub fn of_rig(rig: &Rig) -> Self {
        let unit = rig.disparity_baseline_mm;
        ArrayGeometry {
            names: rig.cameras.iter().map(|c| c.name.clone()).collect(),
            positions: rig
                .cameras
                .iter()
                .map(|c| c.position_mm.map(|v| v / unit))
                .collect(),
        }
    }

    /// A `rows × cols` grid in row-major order, named `r<row>c<col>`, whose vertical
    /// baseline is `baseline_ratio` horizontal ones.
    pub fn grid(rows: usize, cols: usize, baseline_ratio: f64) -> Self {
        let cells = (0..rows * cols).map(|i| (i / cols, i % cols));
        ArrayGeometry {
            names: cells.clone().map(|(r, c)| grid_name(r, c)).collect(),
            positions: cells
                .map(|(r, c)| [c as f64, r as f64 * baseline_ratio])
                .collect(),
        }
    }

    /// The number of views.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether the array has no view.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// The shift per unit disparity of a point of view `from` seen in view `to`:
    /// `(x_to, y_to) = (x_from, y_from) + d · shift`.
    pub fn shift(&self, from: usize, to: usize) -> (f64, f64) {
        let (a, b) = (self.positions[from], self.positions[to]);
        (a[0] - b[0], a[1] - b[1])
    }

    /// View `i`'s neighbours, in view order: the views j that no third view k is nearer to
    /// both than they are to each other (the relative neighbourhood graph). On a grid these
    /// are the row and column neighbours; on a hexagonal array the six around a camera.
    ///
    /// Such a k is nearer to i than j is, so only the views before j in order of distance
    /// from i are tried, and a far view is usually ruled out by one of the first: about
    /// n log n per view instead of n² (`check_search_range` asks for every view's).
    pub fn neighbours(&self, i: usize) -> Vec<usize> {
        let distance = |a: usize, b: usize| {
            let (dx, dy) = self.shift(a, b);
            dx.hypot(dy)
        };
        let mut by_distance: Vec<(f64, usize)> = (0..self.len())
            .filter(|&k| k != i)
            .map(|k| (distance(i, k), k))
            .collect();
        by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut neighbours: Vec<usize> = by_distance
            .iter()
            .enumerate()
            .filter(|&(n, &(dij, j))| {
                !by_distance[..n]
                    .iter()
                    .any(|&(dik, k)| dik.max(distance(j, k)) < dij - SAME_LINE)
            })
            .map(|(_, &(_, j))| j)
            .collect();
        neighbours.sort_unstable();
        neighbours
    }

    /// The nearest view on view `i`'s row (`vertical` false) or column (true), on the
    /// side of increasing x or y (`forward`) or the other: its index and distance.
    pub fn nearest_along(&self, i: usize, vertical: bool, forward: bool) -> Option<(usize, f64)> {
        let (along, across) = if vertical { (1, 0) } else { (0, 1) };
        let me = self.positions[i];
        self.positions
            .iter()
            .enumerate()
            .filter(|(_, p)| (p[across] - me[across]).abs() < SAME_LINE)
            .map(|(j, p)| (j, p[along] - me[along]))
            .filter(|&(_, step)| {
                if forward {
                    step > SAME_LINE
                } else {
                    step < -SAME_LINE
                }
            })
            .map(|(j, step)| (j, step.abs()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// The largest shift component per unit disparity between neighbours: how far the
    /// widest search moves a pixel along the longer baseline.
    pub fn longest_neighbour_shift(&self) -> f64 {
        (0..self.len())
            .flat_map(|i| self.neighbours(i).into_iter().map(move |j| (i, j)))
            .map(|(i, j)| {
                let (dx, dy) = self.shift(i, j);
                dx.abs().max(dy.abs())
            })
            .fold(1.0, f64::max)
    }

    /// The extent of the array along x and y, in disparity baselines.
    pub fn extent(&self) -> [f64; 2] {
        [0, 1].map(|axis| {
            let values = self.positions.iter().map(|p| p[axis]);
            values.clone().fold(f64::NEG_INFINITY, f64::max) - values.fold(f64::INFINITY, f64::min)
        })
    }

    /// The views with other views on both sides along every axis on which the array has
    /// three or more distinct coordinates (every view when there is none).
    pub fn interior_views(&self) -> Vec<usize> {
        let distinct = |axis: usize| {
            let mut values: Vec<f64> = self.positions.iter().map(|p| p[axis]).collect();
            values.sort_by(f64::total_cmp);
            values.dedup_by(|a, b| (*a - *b).abs() < SAME_LINE);
            values.len()
        };
        let axes: Vec<usize> = [0, 1].into_iter().filter(|&a| distinct(a) >= 3).collect();
        let inside = |i: usize| {
            let me = self.positions[i];
            axes.iter().all(|&a| {
                let below = self.positions.iter().any(|p| p[a] < me[a] - SAME_LINE);
                let above = self.positions.iter().any(|p| p[a] > me[a] + SAME_LINE);
                below && above
            })
        };
        let interior: Vec<usize> = (0..self.len()).filter(|&i| inside(i)).collect();
        if interior.is_empty() {
            (0..self.len()).collect()
        } else {
            interior
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shift_follows_the_array_geometry() {
        let g = ArrayGeometry::grid(2, 4, 5.0 / 3.0);
        assert_eq!(g.names[5], "r1c1");
        assert_eq!(g.shift(0, 1), (-1.0, 0.0));
        let (dx, dy) = g.shift(7, 1);
        assert_eq!(dx, 2.0);
        assert!((dy - 5.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn grid_neighbours_are_its_rows_and_columns() {
        // 2×4 with a longer vertical baseline: the camera below is still a neighbour,
        // the diagonal one is not.
        let g = ArrayGeometry::grid(2, 4, 5.0 / 3.0);
        assert_eq!(g.neighbours(0), vec![1, 4]);
        assert_eq!(g.neighbours(5), vec![1, 4, 6]);
        let square = ArrayGeometry::grid(3, 3, 1.0);
        assert_eq!(square.neighbours(4), vec![1, 3, 5, 7]);
        assert_eq!(square.interior_views(), vec![4]);
        assert_eq!(g.interior_views(), vec![1, 2, 5, 6]);
        assert_eq!(g.longest_neighbour_shift(), 5.0 / 3.0);
        assert_eq!(g.nearest_along(5, false, true), Some((6, 1.0)));
        assert_eq!(g.nearest_along(5, true, true), None);
        assert_eq!(g.nearest_along(5, true, false).map(|n| n.0), Some(1));
    }

    #[test]
    fn hexagon_neighbours_are_the_six_around_and_the_ring() {
        // The centre and six cameras at unit distance, flat rows (two at y = 0).
        let s = 3f64.sqrt() / 2.0;
        let mut positions = vec![[0.0, 0.0]];
        positions.extend((0..6).map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_3;
            [a.cos(), a.sin()]
        }));
        let g = ArrayGeometry {
            names: (0..7).map(|k| format!("cam{k}")).collect(),
            positions,
        };
        assert_eq!(g.neighbours(0), vec![1, 2, 3, 4, 5, 6]);
        // A ring camera: the centre and its two ring neighbours, not the far side.
        assert_eq!(g.neighbours(1), vec![0, 2, 6]);
        assert_eq!(g.interior_views(), vec![0]);
        assert_eq!(g.nearest_along(0, false, true), Some((1, 1.0)));
        assert!(g
            .nearest_along(2, false, false)
            .is_some_and(|(j, d)| j == 3 && (d - 1.0).abs() < 1e-12));
        let (dx, dy) = g.shift(0, 2);
        assert!((dx + 0.5).abs() < 1e-12 && (dy + s).abs() < 1e-12);
    }

    /// On an irregular layout of 40 views, the neighbours equal those of the definition
    /// tried against every third view.
    #[test]
    fn neighbours_follow_their_definition_on_an_irregular_layout() {
        let mut state = 99u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            (state >> 33) as f64 / (1u64 << 31) as f64
        };
        let positions: Vec<[f64; 2]> = (0..40).map(|_| [8.0 * next(), 6.0 * next()]).collect();
        let g = ArrayGeometry {
            names: (0..40).map(|k| format!("cam{k}")).collect(),
            positions,
        };
        let distance = |a: usize, b: usize| {
            let (dx, dy) = g.shift(a, b);
            dx.hypot(dy)
        };
        for i in 0..g.len() {
            let defined: Vec<usize> = (0..g.len())
                .filter(|&j| j != i)
                .filter(|&j| {
                    !(0..g.len()).any(|k| {
                        k != i
                            && k != j
                            && distance(i, k).max(distance(j, k)) < distance(i, j) - SAME_LINE
                    })
                })
                .collect();
            assert_eq!(g.neighbours(i), defined, "view {i}");
            assert!(!defined.is_empty());
        }
    }
}
