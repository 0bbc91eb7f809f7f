//! Text boxes from the PP-OCRv5 DBNet probability map.
//!
//! The detector outputs a per-pixel text probability `[1, 1, H, W]`; this
//! module turns it into text-line boxes the way PaddleOCR's `DBPostProcess`
//! does (`box_type = "quad"`, `score_mode = "fast"`), except that the result
//! is an axis-aligned [`Rect`], because everything downstream crops and
//! compares axis-aligned boxes:
//!
//! 1. binarise: `prob > threshold`;
//! 2. take the outer border of every 8-connected region (imageproc's
//!    Suzuki–Abe `find_contours`, as OpenCV's `findContours`) and its
//!    minimum-area rectangle (imageproc's `min_area_rect`, possibly rotated,
//!    corners snapped outwards to whole pixels by imageproc);
//! 3. drop it when its short side is below `min_size`;
//! 4. score it by the mean probability over the pixels inside that rectangle
//!    and drop it below `box_threshold`;
//! 5. unclip: the model predicts text regions shrunk by the Vatti offset
//!    `D = area · unclip_ratio / perimeter` of the rectangle, so the
//!    rectangle grows by `D` on every side; drop it when the grown short
//!    side is below `min_size + 2`;
//! 6. report the axis-aligned bounds of the grown rectangle, clamped to the
//!    map.
//!
//! Contour points are pixel indices, as in PaddleOCR; the reported [`Rect`]
//! adds half a pixel to move to continuous coordinates (pixel `i` spans
//! `[i, i + 1)`), so a region over columns `a..=b` becomes
//! `[a + 0.5 − D, b + 0.5 + D)`: PaddleOCR's width, centred on the region.
//! Holes inside regions are ignored (PaddleOCR's `RETR_LIST` would also box
//! them). Working on rotated rectangles until the last step keeps slanted
//! lines from being scored, size-filtered or unclipped by their much larger
//! axis-aligned bounds. The boxes come out in reading order.

use image::GrayImage;
use imageproc::contours::{find_contours, BorderType};
use imageproc::geometry::min_area_rect;
use imageproc::point::Point;

use crate::geometry::Rect;

/// DBNet post-processing settings; `Default` gives PaddleOCR's values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DbParams {
    /// Binarisation threshold on the probability map.
    pub threshold: f32,
    /// Minimum mean probability inside a box.
    pub box_threshold: f32,
    /// How far boxes grow back, relative to area / perimeter.
    pub unclip_ratio: f32,
    /// Minimum short side, in map pixels (`+ 2` after unclipping).
    pub min_size: f32,
    /// At most this many regions are examined, in raster order.
    pub max_candidates: usize,
}

impl Default for DbParams {
    fn default() -> Self {
        DbParams {
            threshold: 0.3,
            box_threshold: 0.6,
            unclip_ratio: 1.5,
            min_size: 3.0,
            max_candidates: 1000,
        }
    }
}

/// One detected text region.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextBox {
    /// Bounds in probability-map pixels.
    pub rect: Rect,
    /// The grown (possibly rotated) rectangle itself, corners ordered
    /// top-left, top-right, bottom-right, bottom-left as PaddleOCR orders
    /// them for cropping: text in perspective is cut out along it.
    pub quad: [[f32; 2]; 4],
    /// Mean probability inside the (un-grown) region rectangle.
    pub score: f32,
}

/// Text boxes of the `width × height` row-major probability map `prob`, in
/// reading order. Empty when `prob` does not have `width · height` values.
pub fn text_boxes(prob: &[f32], width: usize, height: usize, params: &DbParams) -> Vec<TextBox> {
    let Some(len) = width.checked_mul(height) else {
        return Vec::new();
    };
    // Contours use `i32` pixel coordinates of the padded bitmap.
    let fits = |n: usize| n < i32::MAX as usize - 2;
    if len == 0 || prob.len() != len || !fits(width) || !fits(height) {
        return Vec::new();
    }
    // imageproc's `find_contours` misreads regions touching the image edge
    // (an outer border at x = 0 comes out as a hole); OpenCV pads the image
    // with a zero frame for the same reason, so do that here.
    let (pw, ph) = (width + 2, height + 2);
    let Some(padded_len) = pw.checked_mul(ph) else {
        return Vec::new();
    };
    let mut bits = vec![0u8; padded_len];
    for (dst, src) in bits
        .chunks_exact_mut(pw)
        .skip(1)
        .zip(prob.chunks_exact(width))
    {
        for (d, &p) in dst[1..=width].iter_mut().zip(src) {
            *d = u8::from(p > params.threshold);
        }
    }
    let Some(bitmap) = GrayImage::from_raw(pw as u32, ph as u32, bits) else {
        return Vec::new();
    };
    let map = Map {
        prob,
        width,
        height,
    };
    let boxes = find_contours::<i32>(&bitmap)
        .iter()
        .filter(|c| c.border_type == BorderType::Outer)
        .take(params.max_candidates)
        .filter_map(|c| region_box(&c.points, &map, params))
        .collect();
    reading_order(boxes)
}

struct Map<'a> {
    prob: &'a [f32],
    width: usize,
    height: usize,
}

type Pt = [f32; 2];

/// Steps 2–6 for one region border (points in padded-bitmap coordinates).
fn region_box(points: &[Point<i32>], map: &Map, params: &DbParams) -> Option<TextBox> {
    if points.is_empty() {
        return None;
    }
    // `- 1` undoes the padding.
    let quad = min_area_rect(points).map(|p| [(p.x - 1) as f32, (p.y - 1) as f32]);
    // Corners come as top-left, top-right, bottom-right, bottom-left.
    let (w, h) = (dist(quad[0], quad[1]), dist(quad[0], quad[3]));
    let short = w.min(h);
    if !at_least(short, params.min_size) {
        return None;
    }
    let score = mean_inside(&quad, map);
    if !at_least(score, params.box_threshold) {
        return None;
    }
    let perimeter = 2.0 * (w + h);
    if perimeter.is_nan() || perimeter <= 0.0 {
        return None;
    }
    let d = w * h * params.unclip_ratio / perimeter;
    if !at_least(short + 2.0 * d, params.min_size + 2.0) {
        return None;
    }
    // Grow every corner outwards along both of its sides.
    let u = unit(sub(quad[1], quad[0]));
    let v = unit(sub(quad[3], quad[0]));
    let signs = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
    let mut rect = Rect {
        x0: f32::INFINITY,
        y0: f32::INFINITY,
        x1: f32::NEG_INFINITY,
        y1: f32::NEG_INFINITY,
    };
    let mut grown = [[0.0f32; 2]; 4];
    for ((p, (su, sv)), g) in quad.iter().zip(signs).zip(grown.iter_mut()) {
        let x = p[0] + d * (su * u[0] + sv * v[0]) + 0.5;
        let y = p[1] + d * (su * u[1] + sv * v[1]) + 0.5;
        *g = [x, y];
        rect.x0 = rect.x0.min(x);
        rect.y0 = rect.y0.min(y);
        rect.x1 = rect.x1.max(x);
        rect.y1 = rect.y1.max(y);
    }
    Some(TextBox {
        rect: rect.clamp(map.width as f32, map.height as f32),
        quad: paddle_order(grown),
        score,
    })
}

/// Corners as PaddleOCR's `get_mini_boxes` orders them: of the two
/// leftmost, the upper is top-left and the lower bottom-left; of the two
/// rightmost, the upper is top-right and the lower bottom-right.
fn paddle_order(mut corners: [Pt; 4]) -> [Pt; 4] {
    corners.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let (left, right) = corners.split_at(2);
    let (tl, bl) = if left[0][1] <= left[1][1] {
        (left[0], left[1])
    } else {
        (left[1], left[0])
    };
    let (tr, br) = if right[0][1] <= right[1][1] {
        (right[0], right[1])
    } else {
        (right[1], right[0])
    };
    [tl, tr, br, bl]
}

/// Mean probability over the pixels whose indices lie inside (or on) the
/// convex quadrilateral `quad`, as PaddleOCR's `box_score_fast` does with
/// `fillPoly`; 0 when no pixel does.
fn mean_inside(quad: &[Pt; 4], map: &Map) -> f32 {
    let lo = |i: usize| quad.iter().map(|p| p[i]).fold(f32::INFINITY, f32::min);
    let hi = |i: usize| quad.iter().map(|p| p[i]).fold(f32::NEG_INFINITY, f32::max);
    let span = |lo: f32, hi: f32, n: usize| {
        let last = (n - 1) as f32;
        (lo.floor().clamp(0.0, last) as usize)..=(hi.ceil().clamp(0.0, last) as usize)
    };
    let (mut sum, mut count) = (0.0f64, 0usize);
    for y in span(lo(1), hi(1), map.height) {
        for x in span(lo(0), hi(0), map.width) {
            if inside(quad, [x as f32, y as f32]) {
                sum += f64::from(map.prob[y * map.width + x]);
                count += 1;
            }
        }
    }
    if count == 0 {
        0.0
    } else {
        (sum / count as f64) as f32
    }
}

/// Whether `p` is inside or on the boundary of the convex quadrilateral.
fn inside(quad: &[Pt; 4], p: Pt) -> bool {
    const EPS: f32 = 1e-3;
    let (mut pos, mut neg) = (false, false);
    for i in 0..4 {
        let (a, b) = (quad[i], quad[(i + 1) % 4]);
        let cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        pos |= cross > EPS;
        neg |= cross < -EPS;
    }
    !(pos && neg)
}

/// `value >= min`, false for NaN: a NaN score or size never passes a filter.
fn at_least(value: f32, min: f32) -> bool {
    value >= min
}

fn sub(a: Pt, b: Pt) -> Pt {
    [a[0] - b[0], a[1] - b[1]]
}

fn dist(a: Pt, b: Pt) -> f32 {
    let d = sub(a, b);
    d[0].hypot(d[1])
}

fn unit(a: Pt) -> Pt {
    let n = a[0].hypot(a[1]);
    if n > 0.0 {
        [a[0] / n, a[1] / n]
    } else {
        [0.0, 0.0]
    }
}

/// Top to bottom, then left to right. A box joins the current line when its
/// centre is within half a line height (the smaller of the two boxes') of
/// the line's first box; lines are then ordered by their left edges. Lines
/// are formed first so that the ordering is a true total order.
fn reading_order(mut boxes: Vec<TextBox>) -> Vec<TextBox> {
    boxes.sort_by(|a, b| a.rect.center()[1].total_cmp(&b.rect.center()[1]));
    let mut ordered = Vec::with_capacity(boxes.len());
    let mut line: Vec<TextBox> = Vec::new();
    for b in boxes {
        if let Some(first) = line.first() {
            let tolerance = 0.5 * first.rect.height().min(b.rect.height());
            if b.rect.center()[1] - first.rect.center()[1] > tolerance {
                flush_line(&mut line, &mut ordered);
            }
        }
        line.push(b);
    }
    flush_line(&mut line, &mut ordered);
    ordered
}

fn flush_line(line: &mut Vec<TextBox>, ordered: &mut Vec<TextBox>) {
    line.sort_by(|a, b| a.rect.x0.total_cmp(&b.rect.x0));
    ordered.append(line);
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const W: usize = 40;
    const H: usize = 30;

    /// A `W × H` map of `background` with the given inclusive pixel blocks
    /// `(x0, y0, x1, y1, p)` painted in.
    fn map(background: f32, blocks: &[(usize, usize, usize, usize, f32)]) -> Vec<f32> {
        let mut m = vec![background; W * H];
        for &(x0, y0, x1, y1, p) in blocks {
            for y in y0..=y1 {
                for x in x0..=x1 {
                    m[y * W + x] = p;
                }
            }
        }
        m
    }

    fn approx(a: Rect, b: Rect) {
        let close = |p: f32, q: f32| (p - q).abs() < 1e-4;
        assert!(
            close(a.x0, b.x0) && close(a.y0, b.y0) && close(a.x1, b.x1) && close(a.y1, b.y1),
            "{a:?} != {b:?}"
        );
    }

    /// The expected box of a region over pixel columns `x0..=x1`, rows
    /// `y0..=y1`: sides are `x1 − x0` and `y1 − y0` (contour points are pixel
    /// indices), `D = w h 1.5 / (2 (w + h))`, half a pixel to continuous.
    fn unclipped(x0: f32, y0: f32, x1: f32, y1: f32) -> Rect {
        let (w, h) = (x1 - x0, y1 - y0);
        let d = w * h * 1.5 / (2.0 * (w + h));
        Rect {
            x0: x0 + 0.5 - d,
            y0: y0 + 0.5 - d,
            x1: x1 + 0.5 + d,
            y1: y1 + 0.5 + d,
        }
    }

    #[test]
    fn two_rectangles_unclipped_by_hand() {
        let m = map(0.05, &[(5, 4, 14, 9, 0.9), (20, 15, 35, 22, 0.8)]);
        let boxes = text_boxes(&m, W, H, &DbParams::default());
        assert_eq!(boxes.len(), 2);
        // First: w = 9, h = 5, D = 45 · 1.5 / 28 = 2.410714.
        let d = 45.0 * 1.5 / 28.0;
        approx(
            boxes[0].rect,
            Rect {
                x0: 5.5 - d,
                y0: 4.5 - d,
                x1: 14.5 + d,
                y1: 9.5 + d,
            },
        );
        assert!((boxes[0].score - 0.9).abs() < 1e-5);
        // Second: w = 15, h = 7, D = 105 · 1.5 / 44.
        approx(boxes[1].rect, unclipped(20.0, 15.0, 35.0, 22.0));
        assert!((boxes[1].score - 0.8).abs() < 1e-5);
    }

    #[test]
    fn growth_is_clamped_to_the_map() {
        let m = map(0.0, &[(0, 0, 9, 5, 0.9)]);
        let boxes = text_boxes(&m, W, H, &DbParams::default());
        assert_eq!(boxes.len(), 1);
        let expected = unclipped(0.0, 0.0, 9.0, 5.0);
        approx(
            boxes[0].rect,
            Rect {
                x0: 0.0,
                y0: 0.0,
                ..expected
            },
        );
    }

    #[test]
    fn regions_on_every_edge_are_found() {
        let m = map(0.0, &[(0, 12, 7, 17, 0.9), (30, 24, 39, 29, 0.9)]);
        let boxes = text_boxes(&m, W, H, &DbParams::default());
        assert_eq!(boxes.len(), 2);
        let left = unclipped(0.0, 12.0, 7.0, 17.0);
        approx(boxes[0].rect, Rect { x0: 0.0, ..left });
        let corner = unclipped(30.0, 24.0, 39.0, 29.0);
        approx(
            boxes[1].rect,
            Rect {
                x1: W as f32,
                y1: H as f32,
                ..corner
            },
        );
        let full = text_boxes(&vec![0.9; W * H], W, H, &DbParams::default());
        assert_eq!(full.len(), 1);
        approx(
            full[0].rect,
            Rect {
                x0: 0.0,
                y0: 0.0,
                x1: W as f32,
                y1: H as f32,
            },
        );
    }

    #[test]
    fn low_mean_regions_are_dropped() {
        // Above the bitmap threshold (0.3) but below the box threshold (0.6).
        let m = map(0.0, &[(5, 4, 14, 9, 0.5), (20, 15, 35, 22, 0.9)]);
        let boxes = text_boxes(&m, W, H, &DbParams::default());
        assert_eq!(boxes.len(), 1);
        approx(boxes[0].rect, unclipped(20.0, 15.0, 35.0, 22.0));
    }

    #[test]
    fn score_is_the_mean_over_the_box() {
        // A ring: the hole's low values count towards the mean.
        let mut m = map(0.0, &[(5, 5, 14, 14, 0.9)]);
        for y in 7..=12 {
            for x in 7..=12 {
                m[y * W + x] = 0.0;
            }
        }
        let expected = (64.0 * 0.9) / 100.0;
        let loose = DbParams {
            box_threshold: 0.5,
            ..DbParams::default()
        };
        let boxes = text_boxes(&m, W, H, &loose);
        assert_eq!(boxes.len(), 1, "the hole is not boxed");
        assert!((boxes[0].score - expected).abs() < 1e-5);
        let strict = DbParams {
            box_threshold: 0.6,
            ..DbParams::default()
        };
        assert!(text_boxes(&m, W, H, &strict).is_empty());
    }

    #[test]
    fn tiny_specks_are_dropped() {
        // 3 × 3 pixels: side 2 < min_size 3. 1 × 20: side 0.
        let m = map(0.0, &[(2, 2, 4, 4, 0.95), (10, 3, 29, 3, 0.95)]);
        assert!(text_boxes(&m, W, H, &DbParams::default()).is_empty());
        // 4 × 4 pixels: side 3 passes, 3 + 2 · 1.125 = 5.25 ≥ 5 passes.
        let m = map(0.0, &[(2, 2, 5, 5, 0.95)]);
        let boxes = text_boxes(&m, W, H, &DbParams::default());
        assert_eq!(boxes.len(), 1);
        approx(boxes[0].rect, unclipped(2.0, 2.0, 5.0, 5.0));
    }

    #[test]
    fn unclipped_size_filter() {
        // Side 3 passes min_size 3, but 3 + 2D < 3 + 2 with a small ratio.
        let m = map(0.0, &[(2, 2, 5, 20, 0.95)]);
        let params = DbParams {
            unclip_ratio: 0.5,
            ..DbParams::default()
        };
        assert!(text_boxes(&m, W, H, &params).is_empty());
        assert_eq!(text_boxes(&m, W, H, &DbParams::default()).len(), 1);
    }

    #[test]
    fn slanted_line_is_scored_on_its_rectangle() {
        // A diagonal band: its axis-aligned bounds are mostly background,
        // its minimum-area rectangle is not.
        let mut m = vec![0.0; W * H];
        let (mut sum, mut x_lo, mut x_hi) = (0.0, W, 0);
        for y in 3..25 {
            for x in 0..W {
                if (3..12).contains(&(x as i32 - y as i32)) {
                    m[y * W + x] = 0.9;
                    sum += 0.9;
                    x_lo = x_lo.min(x);
                    x_hi = x_hi.max(x);
                }
            }
        }
        let axis_aligned_mean = sum / ((x_hi - x_lo + 1) * 22) as f32;
        assert!(axis_aligned_mean < 0.6, "{axis_aligned_mean}");
        let boxes = text_boxes(&m, W, H, &DbParams::default());
        assert_eq!(boxes.len(), 1);
        assert!(boxes[0].score > 0.6, "{}", boxes[0].score);
    }

    #[test]
    fn empty_and_malformed_maps() {
        let p = DbParams::default();
        assert!(text_boxes(&vec![0.0; W * H], W, H, &p).is_empty());
        assert!(text_boxes(&vec![1.0; W * H - 1], W, H, &p).is_empty());
        assert!(text_boxes(&[], 0, 0, &p).is_empty());
        assert!(text_boxes(&[1.0], usize::MAX, 2, &p).is_empty());
        let nan = vec![f32::NAN; W * H];
        assert!(text_boxes(&nan, W, H, &p).is_empty());
    }

    #[test]
    fn max_candidates_limits_regions() {
        let m = map(0.0, &[(2, 2, 10, 7, 0.9), (20, 2, 30, 7, 0.9)]);
        let params = DbParams {
            max_candidates: 1,
            ..DbParams::default()
        };
        assert_eq!(text_boxes(&m, W, H, &params).len(), 1);
    }

    #[test]
    fn reading_order_rows_then_columns() {
        // Line 1: right box slightly higher than the left one.
        // Line 2: two boxes below.
        let m = map(
            0.0,
            &[
                (22, 3, 34, 8, 0.9),
                (2, 4, 15, 9, 0.9),
                (25, 18, 36, 23, 0.9),
                (3, 17, 12, 22, 0.9),
            ],
        );
        let boxes = text_boxes(&m, W, H, &DbParams::default());
        let lefts: Vec<i32> = boxes.iter().map(|b| b.rect.center()[0] as i32).collect();
        let tops: Vec<bool> = boxes.iter().map(|b| b.rect.center()[1] < 14.0).collect();
        assert_eq!(tops, [true, true, false, false]);
        assert!(lefts[0] < lefts[1] && lefts[2] < lefts[3], "{lefts:?}");
    }

    proptest! {
        #[test]
        fn never_panics_and_stays_inside(
            (w, h, m) in (1usize..24, 1usize..24).prop_flat_map(|(w, h)| {
                (Just(w), Just(h), proptest::collection::vec(0f32..1.0, w * h))
            })
        ) {
            let params = DbParams { box_threshold: 0.4, min_size: 1.0, ..DbParams::default() };
            for b in text_boxes(&m, w, h, &params) {
                prop_assert!(b.score >= 0.4);
                prop_assert!(b.rect.x0 >= 0.0 && b.rect.x1 <= w as f32);
                prop_assert!(b.rect.y0 >= 0.0 && b.rect.y1 <= h as f32);
                prop_assert!(b.rect.x0 <= b.rect.x1 && b.rect.y0 <= b.rect.y1);
            }
        }
    }
}
