//! The multi-view costs of the array's views: the occlusion-robust cost volume of a view
//! (dot products of learned features along each other view's shift, the smallest mean over
//! a half-array), the cost of one pixel at a fractional disparity, and the half-step costs
//! and equiangular fit of the subpixel stage. See [`super`] for the algorithm.
//!
//! In: every view's compact features and the array's geometry. Out: cost
//! volumes, per-pixel costs and subpixel maps. Each product has a portable build and an
//! AVX-512 BF16 one, tested to agree.

use crate::register::compact_features::{
    dot, dot_widened, widen, CompactFeatures, DotKernel, NeighbourProducts,
};
#[cfg(target_arch = "x86_64")]
use crate::register::compact_features::{
    dot_avx512_bf16, dots16_avx512_bf16, load_bf16, sum_lanes_of_16,
};
use crate::register::ArrayGeometry;
use crate::stereo::{CostVolume, DisparityRange};
use rayon::prelude::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::_mm512_dpbf16_ps;
use std::ops::Range;

/// Multi-view costs of the array's views at any point: a view's cost volume, its
/// half-step costs, and the cost of one of its pixels at a fractional disparity.
pub(super) struct PointCosts<'a> {
    features: &'a [CompactFeatures],
    neighbours: Vec<NeighbourProducts>,
    /// Per view, every other view with its shift and half-arrays ([`others_of`]).
    others: Vec<Vec<OtherView>>,
    kernel: DotKernel,
    pub geometry: &'a ArrayGeometry,
}

impl<'a> PointCosts<'a> {
    pub fn new(features: &'a [CompactFeatures], geometry: &'a ArrayGeometry) -> Self {
        // The half steps' interpolated features take their norms from these.
        let kernel = DotKernel::for_channels(features[0].channels);
        PointCosts {
            features,
            neighbours: neighbour_products(kernel, features),
            others: (0..features.len())
                .map(|i| others_of(geometry, i))
                .collect(),
            kernel,
            geometry,
        }
    }

    /// Width and height of the views.
    pub fn size(&self) -> (usize, usize) {
        (self.features[0].width, self.features[0].height)
    }

    /// View `reference`'s cost volume over `range`.
    pub fn volume(&self, reference: usize, range: DisparityRange) -> CostVolume {
        multi_view_cost_volume(self.features, self.geometry, reference, range)
    }

    /// The cost volume over `range` of the window `columns` × `rows` of view `reference`
    /// (equal to that window of [`PointCosts::volume`]).
    pub fn window_volume(
        &self,
        reference: usize,
        (columns, rows): (Range<usize>, Range<usize>),
        range: DisparityRange,
    ) -> CostVolume {
        let window = Window { columns, rows };
        cost_volume_with(
            self.kernel,
            self.features,
            self.geometry,
            reference,
            range,
            window,
        )
    }

    /// View `reference`'s costs at every pixel's disparity + [`HALF_STEPS`], those `needed`
    /// ([`needed_half_steps`]; NaN where not).
    pub fn half_steps(
        &self,
        reference: usize,
        disparity: &[f32],
        needed: &[[bool; 4]],
    ) -> Vec<[f32; 4]> {
        half_step_costs(
            self.features,
            &self.neighbours,
            self.geometry,
            reference,
            disparity,
            needed,
        )
    }

    /// The cost of view `reference`'s pixel (x, y) at a fractional disparity d.
    pub fn at(&self, reference: usize) -> impl Fn(usize, usize, f32) -> f32 + '_ {
        move |x: usize, y: usize, d: f32| {
            let job = RowJob {
                features: self.features,
                others: &self.others[reference],
                reference: &self.features[reference],
                y,
                columns: 0..self.size().0,
            };
            match self.kernel {
                // The dot products of the neighbours' products, for the same rounding.
                #[cfg(target_arch = "x86_64")]
                DotKernel::Avx512Bf16 => cost_at(&job, &self.neighbours, x, d as f64, |a, b| {
                    // SAFETY: the CPU supports AVX-512F and AVX-512 BF16, and the
                    // features have 16 or a multiple of 32 channels (`for_channels`).
                    unsafe { dot_avx512_bf16(a, b) }
                }),
                _ => cost_at(&job, &self.neighbours, x, d as f64, dot),
            }
        }
    }
}

/// Another view seen from a reference: its index, its shift per unit disparity and the
/// half-arrays it belongs to.
type OtherView = (usize, (f64, f64), [bool; HALVES]);

/// Half-arrays: views left of, right of, above and below the reference.
const HALVES: usize = 4;
/// Fractional row offsets below this are treated as whole rows (one dot product).
const WHOLE_ROW: f64 = 1e-6;

/// Positions (in disparity baselines) closer than this along an axis are level.
const LEVEL: f64 = 1e-6;

/// The half-arrays of the view shifted by `shift` per unit disparity from the reference:
/// left of it (a positive x shift), right, above, below.
fn halves_of((sx, sy): (f64, f64)) -> [bool; HALVES] {
    [sx > LEVEL, sx < -LEVEL, sy > LEVEL, sy < -LEVEL]
}

/// Every view but `reference`: its index, its shift per unit disparity and the half-arrays
/// it belongs to.
fn others_of(geometry: &ArrayGeometry, reference: usize) -> Vec<OtherView> {
    (0..geometry.len())
        .filter(|&v| v != reference)
        .map(|v| {
            let shift = geometry.shift(reference, v);
            (v, shift, halves_of(shift))
        })
        .collect()
}

/// The occlusion-robust multi-view cost volume of view `reference` (see the module docs).
pub fn multi_view_cost_volume(
    features: &[CompactFeatures],
    geometry: &ArrayGeometry,
    reference: usize,
    range: DisparityRange,
) -> CostVolume {
    let kernel = DotKernel::for_channels(features[reference].channels);
    let fr = &features[reference];
    let window = Window {
        columns: 0..fr.width,
        rows: 0..fr.height,
    };
    cost_volume_with(kernel, features, geometry, reference, range, window)
}

/// A window of a view: the columns and rows a cost volume covers.
#[derive(Debug, Clone)]
struct Window {
    columns: Range<usize>,
    rows: Range<usize>,
}

/// [`multi_view_cost_volume`] of the `window` of the reference, with the given build of
/// the dot products.
///
/// Each task takes a few reference rows ([`rows_per_task`]) and, disparity by disparity,
/// each of its rows against every other view, so that the per-half sums of one (row,
/// disparity) stay in L1, and the views' feature rows that the task's next rows and
/// disparities meet again (a lower view's row y0 serves reference rows y0 − (b_y/b_x)·d
/// for every d) may still be in cache.
fn cost_volume_with(
    kernel: DotKernel,
    features: &[CompactFeatures],
    geometry: &ArrayGeometry,
    reference: usize,
    range: DisparityRange,
    window: Window,
) -> CostVolume {
    let fr = &features[reference];
    let disparities = range.count();
    let (w, c) = (fr.width, fr.channels);
    let (columns, top) = (window.columns.clone(), window.rows.start);
    let ww = columns.len();
    let others = others_of(geometry, reference);
    let members: Vec<Vec<usize>> = others
        .iter()
        .map(|(_, _, halves)| (0..HALVES).filter(|&k| halves[k]).collect())
        .collect();
    let mut volume = CostVolume::new(ww, window.rows.len(), range);
    if ww == 0 || disparities == 0 {
        return volume;
    }
    let rows_per_task = rows_per_task(ww * c * std::mem::size_of::<u16>());
    volume
        .data
        .par_chunks_mut(rows_per_task * ww * disparities)
        .enumerate()
        .for_each_init(
            // Per thread: running sums and counts of one (row, disparity) per half-array,
            // laid out [half][x]; the task's reference rows widened to f32 (AVX2 and
            // portable builds).
            || (vec![0f32; HALVES * ww], vec![0u16; HALVES * ww], Vec::new()),
            |(sums, counts, widened), (block, rows)| {
                let first = top + block * rows_per_task;
                let count = rows.len() / (ww * disparities);
                if kernel != DotKernel::Avx512Bf16 {
                    widened.clear();
                    for y in first..first + count {
                        let row = &fr.data[(y * w + columns.start) * c..(y * w + columns.end) * c];
                        widened.extend(row.iter().map(|&v| widen(v)));
                    }
                }
                for k in 0..disparities {
                    let d = range.at(k) as f64;
                    for (i, row) in rows.chunks_exact_mut(ww * disparities).enumerate() {
                        sums.fill(0.0);
                        counts.fill(0);
                        let job = RowJob {
                            features,
                            others: &others,
                            reference: fr,
                            y: first + i,
                            columns: columns.clone(),
                        };
                        let widened_row = &widened[..];
                        let widened_row =
                            widened_row.get(i * ww * c..(i + 1) * ww * c).unwrap_or(&[]);
                        match kernel {
                            // SAFETY: the CPU supports AVX-512F and AVX-512 BF16, and the
                            // features have 16 or a multiple of 32 channels (`for_channels`).
                            #[cfg(target_arch = "x86_64")]
                            DotKernel::Avx512Bf16 => unsafe {
                                accumulate_avx512_bf16(&job, &members, d, sums, counts)
                            },
                            // SAFETY: the CPU supports AVX2 and FMA (`for_channels`).
                            #[cfg(target_arch = "x86_64")]
                            DotKernel::Avx2 => unsafe {
                                accumulate_avx2(&job, &members, d, sums, counts, widened_row)
                            },
                            _ => accumulate_widened(&job, &members, d, sums, counts, widened_row),
                        }
                        for (x, cost) in row.iter_mut().skip(k).step_by(disparities).enumerate() {
                            let mut best = CostVolume::INVALID;
                            for k in 0..HALVES {
                                let j = k * ww + x;
                                if counts[j] > 0 {
                                    best = best.min(sums[j] / counts[j] as f32);
                                }
                            }
                            *cost = best;
                        }
                    }
                }
            },
        );
    volume
}

/// Reference rows per task of the multi-view cost volume, for feature rows of `row_bytes`:
/// [`ROWS_PER_TASK`] up to [`BLOCKED_ROW_BYTES`], else one. On the tabletop the 8 views'
/// volumes took, at 640×480 (80 KB rows), 8.9 and 10.9 s with 8 rows against 10.9 and
/// 12.6 s with one (runs alternated on a loaded machine); at 1920×1080 (240 KB rows),
/// 96.4 s with 8 rows against 78.8 s with one: there the rows of eight reference rows'
/// views no longer stay in cache from one disparity to the next.
fn rows_per_task(row_bytes: usize) -> usize {
    if row_bytes <= BLOCKED_ROW_BYTES {
        ROWS_PER_TASK
    } else {
        1
    }
}

/// See [`rows_per_task`].
const ROWS_PER_TASK: usize = 8;
/// See [`rows_per_task`]: 640 pixels of 64 bfloat16 channels.
const BLOCKED_ROW_BYTES: usize = 640 * 64 * 2;

/// One row's work: the reference row `y` against every other view.
struct RowJob<'a> {
    features: &'a [CompactFeatures],
    others: &'a [(usize, (f64, f64), [bool; HALVES])],
    reference: &'a CompactFeatures,
    y: usize,
    /// The reference columns a cost volume's row covers (its sums are laid out
    /// `[half][x − columns.start]`).
    columns: Range<usize>,
}

/// [`accumulate_widened`] compiled for AVX2 + FMA (the build targets baseline x86-64;
/// 1.5× faster than it at 320×240×64).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn accumulate_avx2(
    job: &RowJob<'_>,
    members: &[Vec<usize>],
    d: f64,
    sums: &mut [f32],
    counts: &mut [u16],
    widened_row: &[f32],
) {
    accumulate_widened(job, members, d, sums, counts, widened_row)
}

/// [`accumulate`] with AVX-512 BF16 on the stored bfloat16, sixteen columns at a time
/// ([`dots16_avx512_bf16`], the costs added to the sums as vectors), the rest one at a time
/// ([`dot_avx512_bf16`]). Where the multi-view cost spends its time: on the tabletop at
/// 640×480 (features of 64 channels) the 8 views' volumes took 8.0–10.2 s one column at
/// a time and 15.2 s with the AVX2 build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16,avx2")]
fn accumulate_avx512_bf16(
    job: &RowJob<'_>,
    members: &[Vec<usize>],
    d: f64,
    sums: &mut [f32],
    counts: &mut [u16],
) {
    use std::arch::x86_64::{
        __m256i, _mm256_add_epi16, _mm256_loadu_si256, _mm256_set1_epi16, _mm256_storeu_si256,
        _mm512_add_ps, _mm512_fmadd_ps, _mm512_fnmadd_ps, _mm512_loadu_ps, _mm512_max_ps,
        _mm512_min_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps, _mm512_sub_ps,
    };
    let fr = job.reference;
    let (w, c) = (fr.width, fr.channels);
    let (x0, ww) = (job.columns.start, job.columns.len());
    let row = &fr.data[job.y * w * c..][..w * c];
    let (half, one) = (_mm512_set1_ps(0.5), _mm512_set1_ps(1.0));
    for_each_view_at(job, members, d, |segment| {
        let mut x = segment.columns.start;
        while x + 16 <= segment.columns.end {
            let xs = (x as isize + segment.offset) as usize;
            let a = &row[x * c..][..16 * c];
            let mut similarity = dots16_avx512_bf16(a, &segment.row[xs * c..], c);
            if let Some((below_row, fy)) = segment.below {
                let below = dots16_avx512_bf16(a, &below_row[xs * c..], c);
                similarity = _mm512_fmadd_ps(
                    _mm512_set1_ps(fy),
                    _mm512_sub_ps(below, similarity),
                    similarity,
                );
            }
            let cost = _mm512_min_ps(
                _mm512_max_ps(
                    _mm512_fnmadd_ps(half, similarity, half),
                    _mm512_setzero_ps(),
                ),
                one,
            );
            for &k in segment.members {
                let j = k * ww + x - x0;
                let (sum, count) = (&mut sums[j..j + 16], &mut counts[j..j + 16]);
                // SAFETY: `sum` holds 16 f32 and `count` 16 u16, what the unaligned loads
                // and stores read and write.
                unsafe {
                    let total = _mm512_add_ps(_mm512_loadu_ps(sum.as_ptr()), cost);
                    _mm512_storeu_ps(sum.as_mut_ptr(), total);
                    let place = count.as_mut_ptr().cast::<__m256i>();
                    let counted = _mm256_add_epi16(_mm256_loadu_si256(place), _mm256_set1_epi16(1));
                    _mm256_storeu_si256(place, counted);
                }
            }
            x += 16;
        }
        for x in x..segment.columns.end {
            let xs = (x as isize + segment.offset) as usize;
            let a = &row[x * c..][..c];
            add_cost(
                &segment,
                x - x0,
                sums,
                counts,
                ww,
                |b| dot_avx512_bf16(a, b),
                xs * c,
                c,
            );
        }
    });
}

/// [`accumulate`] with [`dot_widened`] on the reference row widened to f32 beforehand
/// (`widened_row`), not once per view and disparity.
#[inline(always)]
fn accumulate_widened(
    job: &RowJob<'_>,
    members: &[Vec<usize>],
    d: f64,
    sums: &mut [f32],
    counts: &mut [u16],
    widened_row: &[f32],
) {
    let (c, x0) = (job.reference.channels, job.columns.start);
    accumulate(job, members, d, sums, counts, |x, b| {
        dot_widened(&widened_row[(x - x0) * c..][..c], b)
    });
}

/// Adds the costs of reference row `job.y` at disparity `d` against every other view to
/// the per-half sums and counts (layout `[half][x − job.columns.start]`).
/// `similarity(x, feature)` is the dot product of the reference's feature at column x
/// with another view's feature.
#[inline(always)]
fn accumulate(
    job: &RowJob<'_>,
    members: &[Vec<usize>],
    d: f64,
    sums: &mut [f32],
    counts: &mut [u16],
    similarity: impl Fn(usize, &[u16]) -> f32,
) {
    let c = job.reference.channels;
    let (x0, ww) = (job.columns.start, job.columns.len());
    for_each_view_at(job, members, d, |segment| {
        for x in segment.columns.clone() {
            let xs = (x as isize + segment.offset) as usize;
            add_cost(
                &segment,
                x - x0,
                sums,
                counts,
                ww,
                |b| similarity(x, b),
                xs * c,
                c,
            );
        }
    });
}

/// Adds a column's cost in `segment` to the sums and counts (`[half][x]`, rows of `w`;
/// x counted from the window's first column) of its half-arrays; `product` is the dot product of the reference's feature with one of
/// the view's, whose feature starts at `at` in the segment's rows of `c` channels.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn add_cost(
    segment: &Segment<'_>,
    x: usize,
    sums: &mut [f32],
    counts: &mut [u16],
    w: usize,
    product: impl Fn(&[u16]) -> f32,
    at: usize,
    c: usize,
) {
    let mut similarity = product(&segment.row[at..][..c]);
    if let Some((below_row, fy)) = segment.below {
        let below = product(&below_row[at..][..c]);
        similarity += fy * (below - similarity);
    }
    let cost = (0.5 - 0.5 * similarity).clamp(0.0, 1.0);
    for &k in segment.members {
        let j = k * w + x;
        sums[j] += cost;
        counts[j] += 1;
    }
}

/// The columns of the reference row that one disparity compares with one view.
struct Segment<'a> {
    /// The half-arrays the view belongs to.
    members: &'a [usize],
    /// Reference column x meets the view's column x + offset.
    offset: isize,
    /// The job's reference columns whose match lies inside the view.
    columns: Range<usize>,
    /// The view's features on the row at or above the match.
    row: &'a [u16],
    /// Where the match falls between rows: the row below and the fraction towards it.
    below: Option<(&'a [u16], f32)>,
}

/// The segment of every other view at disparity `d` for reference row `job.y`, in view
/// order (the order of the sums); `members[i]` lists the half-arrays of view i.
#[inline(always)]
fn for_each_view_at(
    job: &RowJob<'_>,
    members: &[Vec<usize>],
    d: f64,
    mut visit: impl FnMut(Segment<'_>),
) {
    let fr = job.reference;
    let (w, h, c, y) = (fr.width, fr.height, fr.channels, job.y);
    for (&(v, (sx, sy), _), members) in job.others.iter().zip(members) {
        let fv = &job.features[v];
        let ys = y as f64 + sy * d;
        if ys < 0.0 || ys > (h - 1) as f64 {
            continue;
        }
        let y0 = ys.floor() as usize;
        let fy = (ys - y0 as f64) as f32;
        let two_rows = fy as f64 > WHOLE_ROW && y0 + 1 < h;
        let offset = (sx * d).round() as isize;
        let x_lo = ((-offset).max(0) as usize).max(job.columns.start);
        let x_hi = ((w as isize - offset.max(0)).max(0) as usize).min(job.columns.end);
        if x_lo >= x_hi {
            continue;
        }
        visit(Segment {
            members,
            offset,
            columns: x_lo..x_hi,
            row: &fv.data[y0 * w * c..][..w * c],
            below: two_rows.then(|| (&fv.data[(y0 + 1) * w * c..][..w * c], fy)),
        });
    }
}

/// Offsets from a pixel's own whole disparity at which [`half_step_costs`] evaluates.
const HALF_STEPS: [f64; 4] = [-1.5, -0.5, 0.5, 1.5];

/// The multi-view cost of reference pixel (x, y) at a fractional disparity `d`: for each
/// view, the cosine with its feature bilinearly interpolated at the shifted position (and
/// renormalised), then the same half-array rule as the volume. NaN if no half-array sees
/// the point. `product` is the dot product of two features ([`dot`] or a faster build).
#[inline(always)]
fn cost_at(
    job: &RowJob<'_>,
    neighbours: &[NeighbourProducts],
    x: usize,
    d: f64,
    product: impl Fn(&[u16], &[u16]) -> f32,
) -> f32 {
    let fr = job.reference;
    let (w, h, c, y) = (fr.width, fr.height, fr.channels, job.y);
    let a = &fr.data[(y * w + x) * c..][..c];
    let (mut sums, mut counts) = ([0f32; HALVES], [0u16; HALVES]);
    for &(v, shift, halves) in job.others {
        let Some((x0, y0, k)) = bilinear_cell((w, h), (x, y), shift, d) else {
            continue;
        };
        let fv = &job.features[v].data;
        let feature = |xx: usize, yy: usize| &fv[(yy * w + xx) * c..][..c];
        let taps = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
        // The cosine with the interpolated feature: a·Σkᵢfᵢ / |Σkᵢfᵢ|. Without the norm,
        // interpolating similarities between two pixels lowers them off the grid and
        // pulls the fit towards whole disparities.
        let mut numerator = 0.0f32;
        for (&ki, &(xi, yi)) in k.iter().zip(&taps) {
            if ki > 0.0 {
                numerator += ki * product(a, feature(xi, yi));
            }
        }
        let norm2 = neighbours[v].interpolated_norm2(x0, y0, k);
        add_interpolated_cost(numerator, norm2, halves, &mut sums, &mut counts);
    }
    least_half_mean(&sums, &counts)
}

/// The bilinear cell of reference pixel (x, y) seen at disparity `d` by a view shifted
/// by `(sx, sy)` per unit disparity in views of `(w, h)`: its top-left pixel and the
/// weights of its four taps (top-left, top-right, bottom-left, bottom-right); None
/// outside the view.
#[inline(always)]
fn bilinear_cell(
    (w, h): (usize, usize),
    (x, y): (usize, usize),
    (sx, sy): (f64, f64),
    d: f64,
) -> Option<(usize, usize, [f32; 4])> {
    let (px, py) = (x as f64 + sx * d, y as f64 + sy * d);
    if px < 0.0 || py < 0.0 || px > (w - 1) as f64 || py > (h - 1) as f64 {
        return None;
    }
    let (x0, y0) = ((px as usize).min(w - 2), (py as usize).min(h - 2));
    let (fx, fy) = ((px - x0 as f64) as f32, (py - y0 as f64) as f32);
    let k = [
        (1.0 - fx) * (1.0 - fy),
        fx * (1.0 - fy),
        (1.0 - fx) * fy,
        fx * fy,
    ];
    Some((x0, y0, k))
}

/// Adds one view's cost, the cosine `numerator / √norm2` with its interpolated feature
/// (0 where the feature is zero), to the sums and counts of the half-arrays it is in.
#[inline(always)]
fn add_interpolated_cost(
    numerator: f32,
    norm2: f32,
    halves: [bool; HALVES],
    sums: &mut [f32; HALVES],
    counts: &mut [u16; HALVES],
) {
    let similarity = if norm2 > 0.0 {
        numerator / norm2.sqrt()
    } else {
        0.0
    };
    let cost = (0.5 - 0.5 * similarity).clamp(0.0, 1.0);
    for k in 0..HALVES {
        if halves[k] {
            sums[k] += cost;
            counts[k] += 1;
        }
    }
}

/// The least mean cost over the half-arrays that saw the point (NaN if none did).
#[inline(always)]
fn least_half_mean(sums: &[f32; HALVES], counts: &[u16; HALVES]) -> f32 {
    (0..HALVES)
        .filter(|&k| counts[k] > 0)
        .map(|k| sums[k] / counts[k] as f32)
        .fold(f32::NAN, f32::min)
}

/// Every pixel's cost at its whole disparity + those of [`HALF_STEPS`] it `needed` (NaN
/// where unknown or not needed). `neighbours` holds every view's [`NeighbourProducts`].
fn half_step_costs(
    features: &[CompactFeatures],
    neighbours: &[NeighbourProducts],
    geometry: &ArrayGeometry,
    reference: usize,
    disparity: &[f32],
    needed: &[[bool; 4]],
) -> Vec<[f32; 4]> {
    let kernel = DotKernel::for_channels(features[reference].channels);
    half_step_costs_with(
        kernel, features, neighbours, geometry, reference, disparity, needed,
    )
}

/// Which of each pixel's [`HALF_STEPS`] [`half_step_subpixel`] may read with a window of
/// `radius` over the whole disparities `disparity`: a pixel's own ±½ steps, and its −1½
/// (+1½) step only where its window holds a disparity below (above) its own, as a pixel
/// one less (more) reads it. A superset of what is read (a window holding d − 2 but not
/// d − 1 still asks for −1½), from separable running minima and maxima; the steps left
/// out are never read, so the fit is the same as with every step (on the tabletop at
/// 320×240 about one pixel in nine needs an outer step).
pub(super) fn needed_half_steps(
    (w, h): (usize, usize),
    disparity: &[f32],
    radius: usize,
) -> Vec<[bool; 4]> {
    // Per pixel, the least and greatest finite disparity of its row segment, then of its
    // window.
    let mut rows = vec![(f32::INFINITY, f32::NEG_INFINITY); w * h];
    rows.par_chunks_mut(w.max(1))
        .zip(disparity.par_chunks(w.max(1)))
        .for_each(|(out, row)| {
            for (x, slot) in out.iter_mut().enumerate() {
                let segment = &row[x.saturating_sub(radius)..(x + radius + 1).min(w)];
                *slot = segment
                    .iter()
                    .filter(|d| d.is_finite())
                    .fold(*slot, |(lo, hi), &d| (lo.min(d), hi.max(d)));
            }
        });
    let mut needed = vec![[false; 4]; w * h];
    needed
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            let column_rows = y.saturating_sub(radius)..(y + radius + 1).min(h);
            for (x, slot) in out.iter_mut().enumerate() {
                let d = disparity[y * w + x];
                if !d.is_finite() {
                    continue;
                }
                let (lo, hi) = column_rows
                    .clone()
                    .map(|yy| rows[yy * w + x])
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), (lo, hi)| {
                        (a.min(lo), b.max(hi))
                    });
                *slot = [lo <= d - 1.0, true, true, hi >= d + 1.0];
            }
        });
    needed
}

/// Every view's [`NeighbourProducts`], with the given build of the dot products.
fn neighbour_products(kernel: DotKernel, features: &[CompactFeatures]) -> Vec<NeighbourProducts> {
    features
        .iter()
        .map(|view| match kernel {
            #[cfg(target_arch = "x86_64")]
            DotKernel::Avx512Bf16 => NeighbourProducts::of(view, |a, b| {
                // SAFETY: the CPU supports AVX-512F and AVX-512 BF16, and the features
                // have 16 or a multiple of 32 channels (checked by `for_channels`).
                unsafe { dot_avx512_bf16(a, b) }
            }),
            _ => NeighbourProducts::of(view, dot),
        })
        .collect()
}

/// [`half_step_costs`] with the given build of the dot products.
fn half_step_costs_with(
    kernel: DotKernel,
    features: &[CompactFeatures],
    neighbours: &[NeighbourProducts],
    geometry: &ArrayGeometry,
    reference: usize,
    disparity: &[f32],
    needed: &[[bool; 4]],
) -> Vec<[f32; 4]> {
    let fr = &features[reference];
    let w = fr.width;
    let others = others_of(geometry, reference);
    let mut out = vec![[f32::NAN; 4]; disparity.len()];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let job = RowJob {
            features,
            others: &others,
            reference: fr,
            y,
            columns: 0..w,
        };
        let disparity = &disparity[y * w..(y + 1) * w];
        let steps = (disparity, &needed[y * w..(y + 1) * w]);
        match kernel {
            // SAFETY: the CPU supports AVX-512F and AVX-512 BF16, and the features have
            // 16 or a multiple of 32 channels (checked by `for_channels`).
            #[cfg(target_arch = "x86_64")]
            DotKernel::Avx512Bf16 => unsafe {
                half_step_row_avx512_bf16(&job, neighbours, steps, row)
            },
            // SAFETY: the CPU supports AVX2 and FMA (checked by `for_channels`).
            #[cfg(target_arch = "x86_64")]
            DotKernel::Avx2 => unsafe { half_step_row_avx2(&job, neighbours, steps, row) },
            _ => half_step_row(&job, neighbours, steps, row, dot),
        }
    });
    out
}

/// One row of [`half_step_costs`], with `product` as [`cost_at`]'s dot product.
#[inline(always)]
fn half_step_row(
    job: &RowJob<'_>,
    neighbours: &[NeighbourProducts],
    (disparity, needed): (&[f32], &[[bool; 4]]),
    row: &mut [[f32; 4]],
    product: impl Fn(&[u16], &[u16]) -> f32 + Copy,
) {
    for (x, ((costs, &d), needs)) in row.iter_mut().zip(disparity).zip(needed).enumerate() {
        if !d.is_finite() {
            continue;
        }
        for ((slot, offset), &need) in costs.iter_mut().zip(HALF_STEPS).zip(needs) {
            if need {
                *slot = cost_at(job, neighbours, x, d as f64 + offset, product);
            }
        }
    }
}

/// [`half_step_row`] compiled for AVX2 + FMA (the half steps' bilinear feature products
/// are most of "SGM + subpixel").
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn half_step_row_avx2(
    job: &RowJob<'_>,
    neighbours: &[NeighbourProducts],
    steps: (&[f32], &[[bool; 4]]),
    row: &mut [[f32; 4]],
) {
    half_step_row(job, neighbours, steps, row, dot)
}

/// [`half_step_row`] with AVX-512 BF16 (features of 16 or a multiple of 32 channels), each
/// interpolated feature's dot product with the reference's reduced sixteen at a time.
///
/// The numerator of a view's cosine, Σᵢ kᵢ (a·fᵢ) over the bilinear taps fᵢ, is the sum
/// of the lanes of Σᵢ kᵢ pᵢ, where pᵢ holds the partial sums of a·fᵢ that `vdpbf16ps`
/// leaves: one vector per view and step, whose lanes are then summed with fifteen other
/// views' and steps' ([`sum_lanes_of_16`]) instead of one reduction per tap. With 16
/// channels a tap and the tap to its right are one load, their partial sums the low and
/// high halves of one product. The rest is [`cost_at`]'s, in its order; the costs equal
/// the portable build's to rounding (the test of every build).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
fn half_step_row_avx512_bf16(
    job: &RowJob<'_>,
    neighbours: &[NeighbourProducts],
    (disparity, needed): (&[f32], &[[bool; 4]]),
    row: &mut [[f32; 4]],
) {
    use std::arch::x86_64::{
        __m256i, __m512, __m512bh, _mm256_loadu_si256, _mm512_broadcast_i64x4, _mm512_fmadd_ps,
        _mm512_mask_blend_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps,
    };
    let fr = job.reference;
    let (w, h, c, y) = (fr.width, fr.height, fr.channels, job.y);
    debug_assert!(c == 16 || c.is_multiple_of(32));
    // Taps waiting for their lanes to be summed: the weighted partial sums, and the
    // step, view and bilinear cell each belongs to.
    let mut weighted = [_mm512_setzero_ps(); 16];
    let mut taps = [(0usize, 0usize, 0usize, 0usize, [0f32; 4]); 16];
    let mut waiting = 0usize;
    // The costs of the waiting taps added to their steps' half-array sums, in order.
    let finish = |weighted: &mut [__m512; 16],
                  taps: &[(usize, usize, usize, usize, [f32; 4])],
                  sums: &mut [[f32; HALVES]; 4],
                  counts: &mut [[u16; HALVES]; 4]| {
        let mut numerators = [0f32; 16];
        // SAFETY: `numerators` holds the 16 f32 the store writes.
        unsafe { _mm512_storeu_ps(numerators.as_mut_ptr(), sum_lanes_of_16(weighted)) };
        for (&(step, other, x0, y0, k), numerator) in taps.iter().zip(numerators) {
            let (v, _, halves) = job.others[other];
            let norm2 = neighbours[v].interpolated_norm2(x0, y0, k);
            add_interpolated_cost(numerator, norm2, halves, &mut sums[step], &mut counts[step]);
        }
        weighted.fill(_mm512_setzero_ps());
    };
    for (x, ((costs, &d), needs)) in row.iter_mut().zip(disparity).zip(needed).enumerate() {
        if !d.is_finite() {
            continue;
        }
        let a = &fr.data[(y * w + x) * c..][..c];
        // With 16 channels: the reference's feature in both halves of a vector.
        let a_twice: __m512bh = if c == 16 {
            // SAFETY: `a` holds 16 u16, the 32 bytes the unaligned load reads; a vector
            // of 32 bf16 has the layout of 32 u16.
            unsafe {
                let low = _mm256_loadu_si256(a.as_ptr().cast::<__m256i>());
                std::mem::transmute::<std::arch::x86_64::__m512i, __m512bh>(_mm512_broadcast_i64x4(
                    low,
                ))
            }
        } else {
            // SAFETY: a vector of 32 bf16 is as many bits as one of 16 f32.
            unsafe { std::mem::transmute::<__m512, __m512bh>(_mm512_setzero_ps()) }
        };
        let mut sums = [[0f32; HALVES]; 4];
        let mut counts = [[0u16; HALVES]; 4];
        for (step, (&offset, &need)) in HALF_STEPS.iter().zip(needs).enumerate() {
            if !need {
                continue;
            }
            let dd = d as f64 + offset;
            for (other, &(v, shift, _)) in job.others.iter().enumerate() {
                let Some((x0, y0, k)) = bilinear_cell((w, h), (x, y), shift, dd) else {
                    continue;
                };
                let fv = &job.features[v].data;
                let sum = &mut weighted[waiting];
                if c == 16 {
                    // Taps (x0, y) and (x0 + 1, y) are 32 consecutive bf16.
                    for (row_y, (k_left, k_right)) in [(y0, (k[0], k[1])), (y0 + 1, (k[2], k[3]))] {
                        if k_left > 0.0 || k_right > 0.0 {
                            let pair = load_bf16(&fv[(row_y * w + x0) * c..][..32]);
                            let products = _mm512_dpbf16_ps(_mm512_setzero_ps(), a_twice, pair);
                            let weights = _mm512_mask_blend_ps(
                                0xFF00,
                                _mm512_set1_ps(k_left),
                                _mm512_set1_ps(k_right),
                            );
                            *sum = _mm512_fmadd_ps(products, weights, *sum);
                        }
                    }
                } else {
                    let cells = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
                    for (&ki, &(xi, yi)) in k.iter().zip(&cells) {
                        if ki > 0.0 {
                            let b = &fv[(yi * w + xi) * c..][..c];
                            let mut products = _mm512_setzero_ps();
                            for (p, q) in a.chunks_exact(32).zip(b.chunks_exact(32)) {
                                products = _mm512_dpbf16_ps(products, load_bf16(p), load_bf16(q));
                            }
                            *sum = _mm512_fmadd_ps(products, _mm512_set1_ps(ki), *sum);
                        }
                    }
                }
                taps[waiting] = (step, other, x0, y0, k);
                waiting += 1;
                if waiting == 16 {
                    finish(&mut weighted, &taps, &mut sums, &mut counts);
                    waiting = 0;
                }
            }
        }
        if waiting > 0 {
            finish(&mut weighted, &taps[..waiting], &mut sums, &mut counts);
            waiting = 0;
        }
        for (step, (slot, &need)) in costs.iter_mut().zip(needs).enumerate() {
            if need {
                *slot = least_half_mean(&sums[step], &counts[step]);
            }
        }
    }
}

/// Per pixel, its costs in `raw` at its whole disparity − 2 … + 2 (NaN outside the
/// volume's range): what [`half_step_subpixel`] reads of a pixel's whole steps.
pub(super) fn whole_steps(raw: &CostVolume, disparity: &[f32]) -> Vec<[f32; 5]> {
    let dm = raw.count();
    raw.data
        .par_chunks(dm.max(1))
        .zip(disparity)
        .map(|(costs, &d)| {
            let mut steps = [f32::NAN; 5];
            if let Some(k) = raw.index_of(d) {
                for (j, step) in steps.iter_mut().enumerate() {
                    if let Some(&cost) = (k + j).checked_sub(2).and_then(|kk| costs.get(kk)) {
                        *step = cost;
                    }
                }
            }
            steps
        })
        .collect()
}

/// [`crate::stereo::windowed_subpixel`] on a half-pixel grid: the window sums of the costs at k − 1,
/// k − ½, k, k + ½, k + 1 (whole steps from the raw volume, [`whole_steps`], half steps
/// from [`half_step_costs`]), an equiangular fit around the least of the three central
/// ones. A pixel whose disparity ± 1 lies outside its volume's range keeps it.
/// A finer grid shrinks the fit's bias towards its samples: on the tabletop at 640×480 the
/// bias at a true offset of 0.3 px fell from −0.07 to −0.02 px and r0c0 gained 0.3 dB
/// (the half steps cost 5 s for 8 views).
///
/// The window of pixel p sums, over the pixels q of its window whose whole disparity is
/// within one of p's, q's five costs around p's disparity. Summing each window pixel by
/// pixel costs (2r + 1)² per pixel; here the view goes in tiles of [`FIT_TILE`], and in a
/// tile the pixels of one disparity L share a summed-area table of what every pixel
/// around them holds for L, so a window is four lookups. The sums are exact, in fixed
/// point ([`FIT_SCALE`]), so a table's differences cancel exactly and the steps a window
/// does not read never change a sum ([`half_step_subpixel_by_pixel`] is the direct sum,
/// the twin the tests compare with).
pub(super) fn half_step_subpixel(
    (w, h): (usize, usize),
    whole: &[[f32; 5]],
    half: &[[f32; 4]],
    disparity: &[f32],
    radius: usize,
) -> Vec<f32> {
    let mut out = disparity.to_vec();
    if w == 0 || h == 0 {
        return out;
    }
    let steps = Steps {
        width: w,
        height: h,
        whole,
        half,
        disparity,
    };
    out.par_chunks_mut(FIT_TILE * w).enumerate().for_each_init(
        FitScratch::default,
        |scratch, (band, out)| {
            let rows = band * FIT_TILE..(band * FIT_TILE + FIT_TILE).min(h);
            for x0 in (0..w).step_by(FIT_TILE) {
                let columns = x0..(x0 + FIT_TILE).min(w);
                steps.fit_tile((columns, rows.clone()), radius, scratch, out);
            }
        },
    );
    out
}

/// Side of the square tiles of [`half_step_subpixel`]: a tile's tables cover it and the
/// window's reach around it.
const FIT_TILE: usize = 64;

/// Fixed-point scale of [`half_step_subpixel`]'s sums: a cost (in [0, 1]) to 2⁻³². A
/// window of 11 × 11 costs sums exactly in i64, and a tile's table stays below 2⁴⁶.
const FIT_SCALE: f64 = 4_294_967_296.0;

/// Largest magnitude a cost may have in the fixed-point sums (costs are in [0, 1]; a
/// larger one is clipped here rather than overflow a table).
const FIT_COST_LIMIT: f64 = 1024.0;

/// The costs [`half_step_subpixel`] reads: per pixel its whole disparity and its costs at
/// whole and half steps around it.
struct Steps<'a> {
    width: usize,
    height: usize,
    whole: &'a [[f32; 5]],
    half: &'a [[f32; 4]],
    disparity: &'a [f32],
}

/// Per thread of [`half_step_subpixel`]: a tile's fitted pixels with their disparities'
/// bits (to group them), and one disparity's summed-area table.
#[derive(Default)]
struct FitScratch {
    pixels: Vec<(u32, u32)>,
    table: Vec<[i64; 5]>,
}

impl Steps<'_> {
    /// Whether pixel i's disparity ± 1 lie in its volume's range (else it keeps its whole
    /// disparity).
    fn fits(&self, i: usize) -> bool {
        self.whole[i][1].is_finite() && self.whole[i][3].is_finite()
    }

    /// Pixel q's five costs around the whole disparity `d` (d − 1, d − ½, d, d + ½, d + 1),
    /// if d is within one of q's and all five are known.
    #[inline(always)]
    fn around(&self, q: usize, d: f32) -> Option<[f32; 5]> {
        let dq = self.disparity[q];
        if !((dq - d).abs() <= 1.0) {
            return None;
        }
        // q's steps sit at dq − 2 … dq + 2 (whole) and dq − 1.5 … dq + 1.5 (half):
        // d − 1 is whole slot d − dq + 1, d − ½ half slot d − dq + 1.
        let slot = ((d - dq) as isize + 1) as usize;
        let (steps, half) = (&self.whole[q][slot..][..3], &self.half[q]);
        let values = [steps[0], half[slot], steps[1], half[slot + 1], steps[2]];
        values.iter().all(|v| v.is_finite()).then_some(values)
    }

    /// Fits the pixels of the tile `columns` × `rows`, writing them to `out` (the rows of
    /// the tile's band, from its first row).
    fn fit_tile(
        &self,
        (columns, rows): (Range<usize>, Range<usize>),
        radius: usize,
        scratch: &mut FitScratch,
        out: &mut [f32],
    ) {
        let (w, h) = (self.width, self.height);
        scratch.pixels.clear();
        for y in rows.clone() {
            for x in columns.clone() {
                let i = y * w + x;
                if self.fits(i) {
                    scratch.pixels.push((self.disparity[i].to_bits(), i as u32));
                }
            }
        }
        scratch.pixels.sort_unstable();
        let pixels = std::mem::take(&mut scratch.pixels);
        for group in pixels.chunk_by(|a, b| a.0 == b.0) {
            let d = self.disparity[group[0].1 as usize];
            // The group's windows, clipped to the view: the table's extent.
            let (mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (w, 0, h, 0);
            for &(_, i) in group {
                let (x, y) = (i as usize % w, i as usize / w);
                (x_lo, x_hi) = (x_lo.min(x), x_hi.max(x));
                (y_lo, y_hi) = (y_lo.min(y), y_hi.max(y));
            }
            let xs = x_lo.saturating_sub(radius)..(x_hi + radius + 1).min(w);
            let ys = y_lo.saturating_sub(radius)..(y_hi + radius + 1).min(h);
            let tw = xs.len() + 1;
            // table[(y + 1) · tw + x + 1]: the sums over the extent's rows up to y and
            // columns up to x; row and column 0 are zero.
            let table = &mut scratch.table;
            table.clear();
            table.resize(tw * (ys.len() + 1), [0; 5]);
            for (ty, y) in ys.clone().enumerate() {
                let mut running = [0i64; 5];
                for (tx, x) in xs.clone().enumerate() {
                    if let Some(values) = self.around(y * w + x, d) {
                        for (sum, v) in running.iter_mut().zip(values) {
                            *sum += fixed_point(v);
                        }
                    }
                    let (above, at) = (ty * tw + tx + 1, (ty + 1) * tw + tx + 1);
                    table[at] = std::array::from_fn(|j| table[above][j] + running[j]);
                }
            }
            for &(_, i) in group {
                let (x, y) = (i as usize % w, i as usize / w);
                // The window in table coordinates: columns l..r, rows t..b.
                let (l, r) = (
                    x.saturating_sub(radius) - xs.start,
                    (x + radius + 1).min(w) - xs.start,
                );
                let (t, b) = (
                    y.saturating_sub(radius) - ys.start,
                    (y + radius + 1).min(h) - ys.start,
                );
                let c: [f32; 5] = std::array::from_fn(|j| {
                    let sum = table[b * tw + r][j] - table[t * tw + r][j] - table[b * tw + l][j]
                        + table[t * tw + l][j];
                    (sum as f64 / FIT_SCALE) as f32
                });
                out[i as usize - rows.start * w] = equiangular_fit(d, c);
            }
        }
        scratch.pixels = pixels;
    }
}

/// A cost in [`FIT_SCALE`]'s fixed point.
#[inline(always)]
fn fixed_point(cost: f32) -> i64 {
    ((cost as f64).clamp(-FIT_COST_LIMIT, FIT_COST_LIMIT) * FIT_SCALE).round() as i64
}

/// The fitted disparity of a pixel of whole disparity `d` whose window sums at d − 1,
/// d − ½, d, d + ½, d + 1 are `c`: an equiangular fit around the least of the three
/// central ones (d where no minimum lies inside).
fn equiangular_fit(d: f32, c: [f32; 5]) -> f32 {
    let m = (1..4).fold(1, |best, j| if c[j] < c[best] { j } else { best });
    let (minus, centre, plus) = (c[m - 1], c[m], c[m + 1]);
    let rise = minus.max(plus) - centre;
    if !(centre <= minus && centre <= plus && rise > 0.0) {
        return d;
    }
    let offset = 0.5 * (m as f32 - 2.0) + 0.5 * ((minus - plus) / (2.0 * rise));
    d + offset.clamp(-0.5, 0.5)
}

/// [`half_step_subpixel`] summing each window pixel by pixel, in f32: the twin the tests
/// compare the tiled sums with.
#[cfg(test)]
fn half_step_subpixel_by_pixel(
    (w, h): (usize, usize),
    whole: &[[f32; 5]],
    half: &[[f32; 4]],
    disparity: &[f32],
    radius: usize,
) -> Vec<f32> {
    let steps = Steps {
        width: w,
        height: h,
        whole,
        half,
        disparity,
    };
    (0..w * h)
        .map(|i| {
            let d = disparity[i];
            if !steps.fits(i) {
                return d;
            }
            let (x, y) = (i % w, i / w);
            let mut c = [0f32; 5];
            for yy in y.saturating_sub(radius)..(y + radius + 1).min(h) {
                for xx in x.saturating_sub(radius)..(x + radius + 1).min(w) {
                    if let Some(values) = steps.around(yy * w + xx, d) {
                        for (sum, v) in c.iter_mut().zip(values) {
                            *sum += v;
                        }
                    }
                }
            }
            equiangular_fit(d, c)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stereo::{winner_take_all, FeatureMap};

    /// Random unit features; view v is view 0 shifted by its disparity along the geometry.
    #[test]
    fn the_true_disparity_has_the_lowest_cost() {
        let (w, h, c, d_true) = (24usize, 20usize, 8usize, 3usize);
        let geometry = ArrayGeometry::grid(2, 2, 1.0);
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
        };
        let base: Vec<f32> = (0..w * h * c).map(|_| next()).collect();
        let positions = [(0, 0), (0, 1), (1, 0), (1, 1)];
        let features: Vec<CompactFeatures> = positions
            .iter()
            .map(|&(r, col)| {
                let mut data = vec![0f32; w * h * c];
                for y in 0..h {
                    for x in 0..w {
                        // View (r, col) sees reference pixel (x, y) at (x − col·d, y − r·d).
                        let (sx, sy) = (x + col * d_true, y + r * d_true);
                        let (sx, sy) = (sx.min(w - 1), sy.min(h - 1));
                        let src = &base[(sy * w + sx) * c..][..c];
                        let norm = src.iter().map(|v| v * v).sum::<f32>().sqrt();
                        for k in 0..c {
                            data[(y * w + x) * c + k] = src[k] / norm;
                        }
                    }
                }
                CompactFeatures::from(FeatureMap {
                    width: w,
                    height: h,
                    channels: c,
                    data,
                })
            })
            .collect();
        // A signed range: the volume's index 0 is disparity −2.
        let range = DisparityRange::new(-2, 6).unwrap();
        let volume = multi_view_cost_volume(&features, &geometry, 0, range);
        let wta = winner_take_all(&volume);
        let (x, y) = (w / 2, h / 2);
        assert_eq!(wta[y * w + x], d_true as f32);
        // bf16 storage: the cosine of identical unit vectors is 1 to about 1e-3.
        assert!(volume.pixel(x, y)[d_true + 2] < 2e-3);
    }

    /// Smooth features; the right view sees them shifted by a fractional disparity, which
    /// the half-step refinement recovers far closer than the whole-step window fit.
    #[test]
    fn half_steps_recover_a_fractional_disparity() {
        let (w, h, c, d_true) = (48usize, 16usize, 8usize, 3.3f64);
        let geometry = ArrayGeometry::grid(1, 2, 1.0);
        let field = |x: f64, y: f64| -> Vec<f32> {
            let v: Vec<f64> = (0..c)
                .map(|k| {
                    (0.25 * x * (1.0 + 0.2 * k as f64) + k as f64).sin()
                        + 0.3 * (0.2 * y + k as f64).cos()
                })
                .collect();
            let norm = v.iter().map(|a| a * a).sum::<f64>().sqrt();
            v.iter().map(|a| (a / norm) as f32).collect()
        };
        let view = |shift: f64| {
            let mut data = Vec::with_capacity(w * h * c);
            for y in 0..h {
                for x in 0..w {
                    // View col 1 sees reference pixel x at x − d: its pixel x shows x + d.
                    data.extend(field(x as f64 + shift, y as f64));
                }
            }
            CompactFeatures::from(FeatureMap {
                width: w,
                height: h,
                channels: c,
                data,
            })
        };
        let features = vec![view(0.0), view(d_true)];
        let range = DisparityRange::up_to(8).unwrap();
        let volume = multi_view_cost_volume(&features, &geometry, 0, range);
        let whole = winner_take_all(&volume);
        let neighbours = neighbour_products(DotKernel::Portable, &features);
        let every = vec![[true; 4]; w * h];
        let half = half_step_costs(&features, &neighbours, &geometry, 0, &whole, &every);
        let steps = whole_steps(&volume, &whole);
        let fine = half_step_subpixel((w, h), &steps, &half, &whole, 3);
        let coarse = crate::stereo::windowed_subpixel(&volume, &whole, 3);
        let (x, y) = (20, 8);
        let i = y * w + x;
        assert_eq!(whole[i], 3.0);
        assert!(
            (fine[i] as f64 - d_true).abs() < 0.03,
            "half steps: {}",
            fine[i]
        );
        assert!(
            (fine[i] as f64 - d_true).abs() < (coarse[i] as f64 - d_true).abs(),
            "half steps {} against whole steps {}",
            fine[i],
            coarse[i]
        );
    }

    /// The half steps [`needed_half_steps`] leaves out are never read: the fit over maps
    /// with steps, edges and holes is bit for bit the fit with every half step.
    #[test]
    fn the_needed_half_steps_give_the_fit_of_every_step() {
        let (w, h, c) = (48usize, 30usize, 16usize);
        let geometry = ArrayGeometry::grid(2, 4, 5.0 / 3.0);
        let mut state = 4242u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
        };
        let features: Vec<CompactFeatures> = (0..geometry.len())
            .map(|_| {
                let data: Vec<f32> = (0..w * h * c).map(|_| next()).collect();
                CompactFeatures::from(FeatureMap {
                    width: w,
                    height: h,
                    channels: c,
                    data,
                })
            })
            .collect();
        let reference = 1;
        let range = DisparityRange::new(-2, 6).unwrap();
        let volume = multi_view_cost_volume(&features, &geometry, reference, range);
        // Plateaus one and two apart, a ramp, and holes.
        let disparity: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                match (x, y) {
                    (_, 0..=9) if x < 20 => 1.0,
                    (_, 0..=9) => 3.0,
                    (_, 10..=19) => (x / 8) as f32 - 1.0,
                    _ if (x + y) % 11 == 0 => f32::NAN,
                    _ => 2.0 + ((x / 13) % 2) as f32,
                }
            })
            .collect();
        let whole = whole_steps(&volume, &disparity);
        let neighbours = neighbour_products(DotKernel::Portable, &features);
        let radius = 3;
        let needed = needed_half_steps((w, h), &disparity, radius);
        let left_out = needed.iter().flatten().filter(|&&n| !n).count();
        assert!(left_out > w * h / 2, "only {left_out} half steps left out");
        let fit = |needed: &[[bool; 4]]| {
            let half = half_step_costs_with(
                DotKernel::Portable,
                &features,
                &neighbours,
                &geometry,
                reference,
                &disparity,
                needed,
            );
            half_step_subpixel((w, h), &whole, &half, &disparity, radius)
        };
        let every = fit(&vec![[true; 4]; w * h]);
        let some = fit(&needed);
        for (i, (a, b)) in every.iter().zip(&some).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "pixel {i}: {a} against {b}");
        }
    }

    /// The tiled fit equals the fit summing each window pixel by pixel, bit for bit, on
    /// costs whose sums are exact in f32 (multiples of 2⁻¹⁰): maps of plateaus, steps of
    /// one and two, ramps across tiles and holes, with unknown steps, over a view of
    /// several tiles and a remainder.
    #[test]
    fn the_tiled_fit_is_the_fit_pixel_by_pixel() {
        let (w, h) = (2 * FIT_TILE + 23, FIT_TILE + 17);
        let mut state = 99u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            (state >> 33) as u32
        };
        let mut cost = || match next() % 50 {
            0 => f32::NAN,
            k => ((k * 37 + next() % 400) % 1025) as f32 / 1024.0,
        };
        let whole: Vec<[f32; 5]> = (0..w * h)
            .map(|_| std::array::from_fn(|_| cost()))
            .collect();
        let half: Vec<[f32; 4]> = (0..w * h)
            .map(|_| std::array::from_fn(|_| cost()))
            .collect();
        let disparity: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                match (x, y) {
                    _ if (3 * x + y) % 17 == 0 => f32::NAN,
                    (_, 0..=20) => ((x / 9) % 5) as f32 - 2.0,
                    (0..=70, _) => 4.0 + ((x + y) / 23) as f32,
                    _ => 6.0 + ((x / 31) % 2) as f32 * 2.0,
                }
            })
            .collect();
        for radius in [0, 3, 5] {
            let tiled = half_step_subpixel((w, h), &whole, &half, &disparity, radius);
            let direct = half_step_subpixel_by_pixel((w, h), &whole, &half, &disparity, radius);
            let fitted = tiled
                .iter()
                .zip(&disparity)
                .filter(|(t, d)| t.is_finite() && t.fract() != 0.0 && d.fract() == 0.0)
                .count();
            assert!(
                fitted > w * h / 4,
                "radius {radius}: only {fitted} pixels moved"
            );
            for (i, (a, b)) in tiled.iter().zip(&direct).enumerate() {
                assert_eq!(
                    a.to_bits(),
                    b.to_bits(),
                    "radius {radius}, pixel {i}: {a} against {b}"
                );
            }
        }
    }

    /// Every build of the dot products this CPU runs gives the portable build's costs, on
    /// features of 16 and 64 channels (the fine and the coarse level's) over a 2×4 array
    /// with fractional row shifts.
    #[test]
    fn every_dot_product_build_gives_the_same_costs() {
        for c in [16, 64] {
            builds_give_the_same_costs(c);
        }
    }

    fn builds_give_the_same_costs(c: usize) {
        let (w, h) = (40usize, 12usize);
        let range = DisparityRange::new(-3, 3).unwrap();
        let geometry = ArrayGeometry::grid(2, 4, 5.0 / 3.0);
        let mut state = 777u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
        };
        let features: Vec<CompactFeatures> = (0..geometry.len())
            .map(|_| {
                let mut data: Vec<f32> = (0..w * h * c).map(|_| next()).collect();
                for feature in data.chunks_exact_mut(c) {
                    let norm = feature.iter().map(|v| v * v).sum::<f32>().sqrt();
                    feature.iter_mut().for_each(|v| *v /= norm);
                }
                CompactFeatures::from(FeatureMap {
                    width: w,
                    height: h,
                    channels: c,
                    data,
                })
            })
            .collect();
        let disparity: Vec<f32> = (0..w * h).map(|i| -1.5 + (i % 3) as f32).collect();
        let kernels = DotKernel::available(c);
        assert_eq!(kernels.last(), Some(&DotKernel::Portable));
        let reference = 5; // r1c1: views on every side
        let whole = || Window {
            columns: 0..w,
            rows: 0..h,
        };
        let portable = cost_volume_with(
            DotKernel::Portable,
            &features,
            &geometry,
            reference,
            range,
            whole(),
        );
        let portable_half = half_step_costs_with(
            DotKernel::Portable,
            &features,
            &neighbour_products(DotKernel::Portable, &features),
            &geometry,
            reference,
            &disparity,
            &vec![[true; 4]; w * h],
        );
        for &kernel in &kernels {
            let volume = cost_volume_with(kernel, &features, &geometry, reference, range, whole());
            // A window of the volume (columns past one 16-wide block) is the same window
            // of the whole one (to rounding: the AVX-512 build's blocks of sixteen columns
            // start where the window does).
            let (columns, rows) = (5..27, 3..10);
            let window = Window {
                columns: columns.clone(),
                rows: rows.clone(),
            };
            let part = cost_volume_with(kernel, &features, &geometry, reference, range, window);
            let n = range.count();
            for (i, y) in rows.enumerate() {
                for (j, x) in columns.clone().enumerate() {
                    let at_part = &part.data[(i * columns.len() + j) * n..][..n];
                    let at_whole = &volume.data[(y * w + x) * n..][..n];
                    let off = at_part
                        .iter()
                        .zip(at_whole)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0f32, f32::max);
                    assert!(off < 1e-6, "{kernel:?}: window at ({x}, {y}) off by {off}");
                }
            }
            let worst = volume
                .data
                .iter()
                .zip(&portable.data)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(
                worst < 1e-5,
                "{kernel:?}, {c} channels: volume off by {worst}"
            );
            let half = half_step_costs_with(
                kernel,
                &features,
                &neighbour_products(kernel, &features),
                &geometry,
                reference,
                &disparity,
                &vec![[true; 4]; w * h],
            );
            let worst = half
                .iter()
                .flatten()
                .zip(portable_half.iter().flatten())
                .filter(|(a, b)| a.is_finite() || b.is_finite())
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(
                worst < 1e-5,
                "{kernel:?}, {c} channels: half steps off by {worst}"
            );
        }
    }
}
