//! ORB feature extraction (oriented FAST + steered rBRIEF), shaped after
//! ORB-SLAM3's `ORBextractor` so that the bag-of-words baseline sees the same
//! kind of features as that system's own place recognition.
//!
//! The pipeline per image is ORB-SLAM3's:
//! 1. a scale pyramid (`n_levels`, each `scale_factor` smaller, bilinear);
//! 2. FAST-9 corners per level, kept at least [`EDGE_THRESHOLD`] px from the
//!    border; in each 35 px cell the threshold is `ini_fast_threshold`, or
//!    `min_fast_threshold` where the cell has no corner that strong
//!    (3x3 non-maximum suppression on the FAST score);
//! 3. a quadtree ("octree" in ORB-SLAM) spreads the corners over the level,
//!    keeping the strongest corner in each node, up to the level's share of
//!    `n_features` (shares fall geometrically with the level's area);
//! 4. orientation from the intensity centroid of the 31 px circular patch;
//! 5. a 256-bit rBRIEF on the level blurred with a 7x7, sigma 2 Gaussian,
//!    its test pattern rotated by the orientation.
//!
//! FAST detection, non-maximum suppression and separable filtering come from
//! `imageproc`, pyramid resizing from `fast_image_resize`. The ORB-specific
//! parts — cell thresholds, quadtree distribution, intensity-centroid angle
//! and the steered test pattern — are written here: `imageproc`'s
//! `oriented_fast` keeps the top corners of one scale without spreading
//! them, and its `brief` neither steers the pattern nor takes ORB's learned
//! one.

use fast_image_resize as fir;
use image::{imageops, GrayImage};
use imageproc::corners::{corners_fast9, Corner};
use imageproc::filter::separable_filter_equal;
use imageproc::suppress::local_maxima;

use super::pattern::BIT_PATTERN_31;

/// A 256-bit binary ORB descriptor.
pub type Descriptor = [u8; 32];

/// Pixels kept free at each level's border (ORB-SLAM3's `EDGE_THRESHOLD`):
/// the steered 31 px pattern reaches 18 px from the keypoint.
pub const EDGE_THRESHOLD: u32 = 19;
/// Half the side of the orientation and descriptor patch (31 px).
const HALF_PATCH_SIZE: usize = 15;
/// Side of the cells that choose their own FAST threshold (ORB-SLAM3's `W`).
const CELL_SIZE: f32 = 35.0;
/// Half-width of each row of the circular 31 px patch, for rows 0..=15
/// (OpenCV's `umax`, made symmetric so the patch is the same after a
/// transposition; `circle_rows_match_opencv` recomputes it).
const UMAX: [i32; HALF_PATCH_SIZE + 1] =
    [15, 15, 15, 15, 14, 14, 14, 13, 13, 12, 11, 10, 9, 8, 6, 3];

/// ORB extraction settings; the defaults are ORB-SLAM3's (its EuRoC/TUM
/// settings files: 1000 features, scale 1.2, 8 levels, FAST 20 / 7).
#[derive(Clone, Debug, PartialEq)]
pub struct OrbParams {
    /// Features wanted over the whole pyramid.
    pub n_features: usize,
    /// Size ratio between consecutive pyramid levels; at or below 1 only
    /// level 0 is used.
    pub scale_factor: f32,
    /// Number of pyramid levels (level 0 is the input image).
    pub n_levels: usize,
    /// FAST threshold tried first in each cell.
    pub ini_fast_threshold: u8,
    /// FAST threshold used in cells where the first finds nothing.
    pub min_fast_threshold: u8,
}

impl Default for OrbParams {
    fn default() -> Self {
        Self {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            ini_fast_threshold: 20,
            min_fast_threshold: 7,
        }
    }
}

/// A detected keypoint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyPoint {
    /// Column in level-0 (input image) pixels (pixel centres at integers).
    pub x: f32,
    /// Row in level-0 pixels.
    pub y: f32,
    /// Pyramid level it was found at.
    pub level: usize,
    /// Orientation in radians, `atan2(m01, m10)` of the intensity centroid
    /// with y pointing down (so +π/2 points down the image).
    pub angle: f32,
    /// FAST score (largest threshold at which it is still a corner).
    pub response: f32,
}

/// Extracts ORB descriptors (grouped by pyramid level, finest first).
pub fn extract(image: &GrayImage, params: &OrbParams) -> Vec<Descriptor> {
    detect_and_describe(image, params)
        .into_iter()
        .map(|(_, d)| d)
        .collect()
}

/// Detects ORB keypoints and computes their descriptors.
pub fn detect_and_describe(image: &GrayImage, params: &OrbParams) -> Vec<(KeyPoint, Descriptor)> {
    let n_levels = if params.scale_factor > 1.0 {
        params.n_levels
    } else {
        params.n_levels.min(1)
    };
    let per_level = features_per_level(params.n_features, params.scale_factor, n_levels);
    let kernel = gaussian_kernel_7x7();
    let mut out = Vec::with_capacity(params.n_features + params.n_features / 10);
    let mut level_image = image.clone();
    let mut resizer = fir::Resizer::new();
    for (level, &wanted) in per_level.iter().enumerate() {
        if level > 0 {
            let inv = 1.0 / params.scale_factor.powi(level as i32);
            let w = (image.width() as f32 * inv).round() as u32;
            let h = (image.height() as f32 * inv).round() as u32;
            if !fits_patch(w, h) {
                break;
            }
            // ORB-SLAM3 resizes each level from the previous one.
            level_image = downscale(&mut resizer, &level_image, w, h);
        }
        let corners = detect_level(&level_image, params, wanted);
        if corners.is_empty() {
            continue;
        }
        let blurred = separable_filter_equal(&level_image, &kernel);
        let scale = params.scale_factor.powi(level as i32);
        for c in corners {
            let angle = intensity_centroid_angle(&level_image, c.x, c.y);
            let descriptor = steered_brief(&blurred, c.x, c.y, angle);
            let kp = KeyPoint {
                x: (c.x as f32 + 0.5) * scale - 0.5,
                y: (c.y as f32 + 0.5) * scale - 0.5,
                level,
                angle,
                response: c.score,
            };
            out.push((kp, descriptor));
        }
    }
    out
}

/// Hamming distance between two descriptors.
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    // Four 64-bit words: about 3x faster than byte-wise on baseline x86-64.
    let (a, _) = a.as_chunks::<8>();
    let (b, _) = b.as_chunks::<8>();
    a.iter()
        .zip(b)
        .map(|(x, y)| (u64::from_ne_bytes(*x) ^ u64::from_ne_bytes(*y)).count_ones())
        .sum()
}

/// Bilinear resize with `fast_image_resize` (SIMD), falling back to
/// `image`'s triangle filter should it refuse the buffers.
fn downscale(resizer: &mut fir::Resizer, image: &GrayImage, w: u32, h: u32) -> GrayImage {
    let options = fir::ResizeOptions::new()
        .resize_alg(fir::ResizeAlg::Convolution(fir::FilterType::Bilinear));
    let mut dst = fir::images::Image::new(w, h, fir::PixelType::U8);
    let resized = fir::images::ImageRef::new(
        image.width(),
        image.height(),
        image.as_raw(),
        fir::PixelType::U8,
    )
    .ok()
    .and_then(|src| resizer.resize(&src, &mut dst, &options).ok())
    .and_then(|()| GrayImage::from_raw(w, h, dst.into_vec()));
    resized.unwrap_or_else(|| imageops::resize(image, w, h, imageops::FilterType::Triangle))
}

/// Whether a level of this size has room for a keypoint away from the border.
fn fits_patch(w: u32, h: u32) -> bool {
    w > 2 * EDGE_THRESHOLD && h > 2 * EDGE_THRESHOLD
}

/// Each level's share of `n_features`, falling by `1/scale_factor` per level
/// (ORB-SLAM3's `mnFeaturesPerLevel`; the last level takes the remainder).
fn features_per_level(n_features: usize, scale_factor: f32, n: usize) -> Vec<usize> {
    if n == 0 {
        return Vec::new();
    }
    let factor = 1.0 / scale_factor;
    let mut desired = n_features as f32 * (1.0 - factor) / (1.0 - factor.powi(n as i32));
    if !desired.is_finite() {
        // scale_factor == 1: equal shares.
        desired = n_features as f32 / n as f32;
    }
    let mut shares = Vec::with_capacity(n);
    let mut sum = 0usize;
    for _ in 0..n - 1 {
        let share = desired.round().max(0.0) as usize;
        shares.push(share);
        sum += share;
        desired *= factor;
    }
    shares.push(n_features.saturating_sub(sum));
    shares
}

/// FAST corners of one level with ORB-SLAM3's per-cell threshold fallback,
/// spread by the quadtree down to about `wanted` corners.
fn detect_level(image: &GrayImage, params: &OrbParams, wanted: usize) -> Vec<Corner> {
    let (w, h) = image.dimensions();
    if wanted == 0 || !fits_patch(w, h) {
        return Vec::new();
    }
    let low = params.min_fast_threshold.min(params.ini_fast_threshold);
    let inside = |c: &Corner| {
        c.x >= EDGE_THRESHOLD
            && c.y >= EDGE_THRESHOLD
            && c.x < w - EDGE_THRESHOLD
            && c.y < h - EDGE_THRESHOLD
    };
    let candidates: Vec<Corner> = corners_fast9(image, low)
        .into_iter()
        .filter(inside)
        .collect();
    let corners = local_maxima(&candidates, 1);

    // ORB-SLAM3's cell grid over the detection area [EDGE-3, size-EDGE+3).
    let span_x = (w - 2 * EDGE_THRESHOLD + 6) as f32;
    let span_y = (h - 2 * EDGE_THRESHOLD + 6) as f32;
    let n_cols = ((span_x / CELL_SIZE) as usize).max(1);
    let n_rows = ((span_y / CELL_SIZE) as usize).max(1);
    let cell_w = (span_x / n_cols as f32).ceil() as u32;
    let cell_h = (span_y / n_rows as f32).ceil() as u32;
    let cell_of = |c: &Corner| {
        let col = (((c.x - EDGE_THRESHOLD) / cell_w) as usize).min(n_cols - 1);
        let row = (((c.y - EDGE_THRESHOLD) / cell_h) as usize).min(n_rows - 1);
        row * n_cols + col
    };
    let strong = f32::from(params.ini_fast_threshold);
    let mut cell_has_strong = vec![false; n_cols * n_rows];
    for c in corners.iter().filter(|c| c.score >= strong) {
        cell_has_strong[cell_of(c)] = true;
    }
    let kept: Vec<Corner> = corners
        .into_iter()
        .filter(|c| c.score >= strong || !cell_has_strong[cell_of(c)])
        .collect();

    let border = (EDGE_THRESHOLD - 3) as f32;
    let bounds = Rect {
        x0: border,
        x1: (w - EDGE_THRESHOLD + 3) as f32,
        y0: border,
        y1: (h - EDGE_THRESHOLD + 3) as f32,
    };
    distribute_quadtree(&kept, bounds, wanted)
}

/// Axis-aligned box of a quadtree node.
#[derive(Clone, Copy, Debug)]
struct Rect {
    x0: f32,
    x1: f32,
    y0: f32,
    y1: f32,
}

/// A quadtree node and the corners (indices) inside it.
struct Node {
    rect: Rect,
    keys: Vec<usize>,
}

impl Node {
    fn can_split(&self) -> bool {
        self.keys.len() > 1
            && (self.rect.x1 - self.rect.x0 > 0.5 || self.rect.y1 - self.rect.y0 > 0.5)
    }

    /// The non-empty quarters of this node.
    fn split(self, corners: &[Corner]) -> Vec<Node> {
        let r = self.rect;
        let (mx, my) = (r.x0 + 0.5 * (r.x1 - r.x0), r.y0 + 0.5 * (r.y1 - r.y0));
        let mut quarters: [Vec<usize>; 4] = Default::default();
        for k in self.keys {
            let c = &corners[k];
            let q = usize::from(c.x as f32 >= mx) + 2 * usize::from(c.y as f32 >= my);
            quarters[q].push(k);
        }
        quarters
            .into_iter()
            .enumerate()
            .filter(|(_, keys)| !keys.is_empty())
            .map(|(q, keys)| {
                let (x0, x1) = if q % 2 == 0 { (r.x0, mx) } else { (mx, r.x1) };
                let (y0, y1) = if q < 2 { (r.y0, my) } else { (my, r.y1) };
                Node {
                    rect: Rect { x0, x1, y0, y1 },
                    keys,
                }
            })
            .collect()
    }
}

/// ORB-SLAM3's `DistributeOctTree`: split the area into quadtree nodes until
/// there are about `wanted` non-empty ones (splitting all nodes per round,
/// the most crowded first once a full round would overshoot), then keep the
/// strongest corner of each node. Spreads features over the image instead
/// of piling them on the most textured spot.
fn distribute_quadtree(corners: &[Corner], bounds: Rect, wanted: usize) -> Vec<Corner> {
    if corners.is_empty() || wanted == 0 {
        return Vec::new();
    }
    let width = bounds.x1 - bounds.x0;
    let height = bounds.y1 - bounds.y0;
    let n_roots = ((width / height).round() as usize).max(1);
    let root_w = width / n_roots as f32;
    let mut roots: Vec<Vec<usize>> = vec![Vec::new(); n_roots];
    for (i, c) in corners.iter().enumerate() {
        let r = (((c.x as f32 - bounds.x0) / root_w) as usize).min(n_roots - 1);
        roots[r].push(i);
    }
    let mut nodes: Vec<Node> = roots
        .into_iter()
        .enumerate()
        .filter(|(_, keys)| !keys.is_empty())
        .map(|(r, keys)| Node {
            rect: Rect {
                x0: bounds.x0 + r as f32 * root_w,
                x1: bounds.x0 + (r + 1) as f32 * root_w,
                ..bounds
            },
            keys,
        })
        .collect();

    while nodes.len() < wanted {
        let splittable = nodes.iter().filter(|n| n.can_split()).count();
        if splittable == 0 {
            break;
        }
        if nodes.len() + 3 * splittable <= wanted {
            // A full round cannot overshoot: split every node.
            let mut next = Vec::with_capacity(nodes.len() + 3 * splittable);
            for node in nodes {
                if node.can_split() {
                    next.extend(node.split(corners));
                } else {
                    next.push(node);
                }
            }
            nodes = next;
        } else {
            // Last round: split the most crowded nodes first, stop at `wanted`.
            let mut order: Vec<usize> =
                (0..nodes.len()).filter(|&i| nodes[i].can_split()).collect();
            order.sort_by_key(|&i| std::cmp::Reverse(nodes[i].keys.len()));
            for i in order {
                let node = std::mem::replace(
                    &mut nodes[i],
                    Node {
                        rect: bounds,
                        keys: Vec::new(),
                    },
                );
                let mut children = node.split(corners).into_iter();
                if let Some(first) = children.next() {
                    nodes[i] = first;
                }
                nodes.extend(children);
                if nodes.len() >= wanted {
                    break;
                }
            }
        }
    }

    nodes
        .iter()
        .filter_map(|n| {
            n.keys
                .iter()
                .map(|&k| corners[k])
                .reduce(|best, c| if c.score > best.score { c } else { best })
        })
        .collect()
}

/// Orientation of the 31 px circular patch at `(x, y)`: the angle of the
/// vector from the centre to the intensity centroid, `atan2(m01, m10)` with
/// y down. The caller keeps `(x, y)` at least 15 px inside the image.
fn intensity_centroid_angle(image: &GrayImage, x: u32, y: u32) -> f32 {
    let w = image.width() as isize;
    let data = image.as_raw();
    let center = y as isize * w + x as isize;
    let px = |offset: isize| i64::from(data[(center + offset) as usize]);
    let half = HALF_PATCH_SIZE as isize;
    let mut m10: i64 = (-half..=half).map(|u| u as i64 * px(u)).sum();
    let mut m01: i64 = 0;
    for v in 1..=half {
        let d = UMAX[v as usize] as isize;
        let mut v_sum = 0;
        for u in -d..=d {
            let below = px(u + v * w);
            let above = px(u - v * w);
            v_sum += below - above;
            m10 += u as i64 * (below + above);
        }
        m01 += v as i64 * v_sum;
    }
    (m01 as f32).atan2(m10 as f32)
}

/// ORB's steered BRIEF: the learned test pattern rotated by `angle`, sampled
/// (nearest pixel) on the blurred level. The caller keeps `(x, y)` at least
/// [`EDGE_THRESHOLD`] px inside the image.
fn steered_brief(blurred: &GrayImage, x: u32, y: u32, angle: f32) -> Descriptor {
    let (sin, cos) = angle.sin_cos();
    let w = blurred.width() as isize;
    let data = blurred.as_raw();
    let center = y as isize * w + x as isize;
    let sample = |px: i8, py: i8| {
        let (fx, fy) = (f32::from(px), f32::from(py));
        let ix = round_half_even(fx * cos - fy * sin);
        let iy = round_half_even(fx * sin + fy * cos);
        data[(center + iy * w + ix) as usize]
    };
    let mut descriptor = [0u8; 32];
    for (i, &[x0, y0, x1, y1]) in BIT_PATTERN_31.iter().enumerate() {
        if sample(x0, y0) < sample(x1, y1) {
            descriptor[i / 8] |= 1 << (i % 8);
        }
    }
    descriptor
}

/// Rounds to the nearest integer, ties to even, like OpenCV's `cvRound`, for
/// |x| < 2^22: adding and removing 1.5 * 2^23 leaves no fraction bits.
/// (`f32::round_ties_even` is a libm call on baseline x86-64 and took a
/// seventh of the extraction time.)
#[inline]
fn round_half_even(x: f32) -> isize {
    const MAGIC: f32 = 12_582_912.0;
    ((x + MAGIC) - MAGIC) as isize
}

/// OpenCV's 7-tap Gaussian with sigma 2 (ORB-SLAM3 blurs with `Size(7, 7), 2`).
fn gaussian_kernel_7x7() -> [f32; 7] {
    let mut k = [0f32; 7];
    for (i, v) in k.iter_mut().enumerate() {
        let d = i as f32 - 3.0;
        *v = (-d * d / 8.0).exp();
    }
    let sum: f32 = k.iter().sum();
    k.map(|v| v / sum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Luma;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};
    use std::f32::consts::{FRAC_PI_2, PI};

    /// Angle difference wrapped to (-π, π].
    fn wrap(a: f32) -> f32 {
        let mut d = a % (2.0 * PI);
        if d > PI {
            d -= 2.0 * PI;
        } else if d <= -PI {
            d += 2.0 * PI;
        }
        d
    }

    /// A deterministic cluttered scene: random rectangles and discs on noise.
    fn textured(w: u32, h: u32, seed: u64) -> GrayImage {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut img = GrayImage::from_fn(w, h, |_, _| Luma([rng.random_range(100..110u8)]));
        for _ in 0..60 {
            let (x0, y0) = (rng.random_range(0..w), rng.random_range(0..h));
            let (rw, rh) = (rng.random_range(4..40), rng.random_range(4..40));
            let value = rng.random_range(0..=255u8);
            let disc = rng.random_bool(0.5);
            for y in y0..(y0 + rh).min(h) {
                for x in x0..(x0 + rw).min(w) {
                    let (dx, dy) = (
                        x as f32 - (x0 + rw / 2) as f32,
                        y as f32 - (y0 + rh / 2) as f32,
                    );
                    if !disc || dx * dx + dy * dy <= (rw.min(rh) as f32 / 2.0).powi(2) {
                        img.put_pixel(x, y, Luma([value]));
                    }
                }
            }
        }
        img
    }

    #[test]
    fn circle_rows_match_opencv() {
        // OpenCV's recipe for `umax` (orb.cpp), recomputed.
        let half = HALF_PATCH_SIZE;
        let mut umax = [0i32; HALF_PATCH_SIZE + 2];
        let vmax = (half as f64 * 2f64.sqrt() / 2.0 + 1.0).floor() as usize;
        let vmin = (half as f64 * 2f64.sqrt() / 2.0).ceil() as usize;
        for (v, u) in umax.iter_mut().enumerate().take(vmax + 1) {
            *u = ((half * half - v * v) as f64).sqrt().round_ties_even() as i32;
        }
        let mut v0 = 0;
        for v in (vmin..=half).rev() {
            while umax[v0] == umax[v0 + 1] {
                v0 += 1;
            }
            umax[v] = v0 as i32;
            v0 += 1;
        }
        assert_eq!(&umax[..=half], &UMAX[..]);
        // The disc is symmetric under transposition: (u, v) in => (v, u) in.
        for v in 0..=half as i32 {
            for u in 0..=UMAX[v as usize] {
                assert!(
                    v <= UMAX[u as usize],
                    "({u}, {v}) in the disc but not ({v}, {u})"
                );
            }
        }
    }

    #[test]
    fn rounding_matches_round_ties_even() {
        for i in -4000..=4000 {
            let x = i as f32 * 0.0125;
            assert_eq!(round_half_even(x), x.round_ties_even() as isize, "x = {x}");
        }
        assert_eq!(round_half_even(2.5), 2);
        assert_eq!(round_half_even(-0.5), 0);
        assert_eq!(round_half_even(-1.5), -2);
    }

    #[test]
    fn features_per_level_follow_orb_slam() {
        let shares = features_per_level(1000, 1.2, 8);
        assert_eq!(shares.len(), 8);
        assert_eq!(shares.iter().sum::<usize>(), 1000);
        // 1000 * (1 - 1/1.2) / (1 - 1.2^-8) = 217.3
        assert_eq!(shares[0], 217);
        assert!(shares.windows(2).all(|w| w[0] >= w[1]));
        assert_eq!(features_per_level(500, 1.0, 1), vec![500]);
        assert_eq!(features_per_level(500, 1.0, 4), vec![125; 4]);
    }

    #[test]
    fn bright_square_gives_keypoints_at_its_corners() {
        let mut img = GrayImage::from_pixel(200, 160, Luma([40]));
        for y in 60..100 {
            for x in 80..120 {
                img.put_pixel(x, y, Luma([200]));
            }
        }
        let corners = [(80.0, 60.0), (119.0, 60.0), (80.0, 99.0), (119.0, 99.0)];
        let kps: Vec<KeyPoint> = detect_and_describe(&img, &OrbParams::default())
            .into_iter()
            .map(|(k, _)| k)
            .collect();
        assert!(!kps.is_empty());
        let dist =
            |k: &KeyPoint, c: &(f32, f32)| ((k.x - c.0).powi(2) + (k.y - c.1).powi(2)).sqrt();
        for k in &kps {
            // Nothing in the flat areas at any level...
            let margin = 3.0 * 1.2f32.powi(k.level as i32);
            assert!(
                k.x > 80.0 - margin
                    && k.x < 119.0 + margin
                    && k.y > 60.0 - margin
                    && k.y < 99.0 + margin,
                "keypoint {k:?} away from the square"
            );
            // ...and only corners while the square is still large (>= 20 px).
            if k.level <= 4 {
                let nearest = corners.iter().map(|c| dist(k, c)).fold(f32::MAX, f32::min);
                assert!(
                    nearest <= margin,
                    "keypoint {k:?} is {nearest} px from every corner"
                );
            }
        }
        for c in &corners {
            assert!(
                kps.iter().any(|k| k.level == 0 && dist(k, c) <= 2.0),
                "no level-0 keypoint at corner {c:?}"
            );
        }
    }

    #[test]
    fn orientation_points_at_the_bright_side() {
        for degrees in [0.0f32, 30.0, 90.0, 135.0, 200.0, 300.0] {
            let theta = degrees.to_radians();
            let (cx, cy) = (32.0 + 9.0 * theta.cos(), 32.0 + 9.0 * theta.sin());
            let img = GrayImage::from_fn(64, 64, |x, y| {
                let inside = (x as f32 - cx).powi(2) + (y as f32 - cy).powi(2) <= 9.0;
                Luma([if inside { 255 } else { 10 }])
            });
            let angle = intensity_centroid_angle(&img, 32, 32);
            assert!(
                wrap(angle - theta).abs() < 4f32.to_radians(),
                "blob at {degrees} deg, angle {} deg",
                angle.to_degrees()
            );
        }
    }

    #[test]
    fn orientation_rotates_with_the_image() {
        let img = textured(64, 48, 7);
        let rotated = imageops::rotate90(&img); // clockwise: (x, y) -> (h - 1 - y, x)
        for (x, y) in [(20, 20), (32, 24), (40, 30)] {
            let a = intensity_centroid_angle(&img, x, y);
            let b = intensity_centroid_angle(&rotated, 48 - 1 - y, x);
            assert!(wrap(b - a - FRAC_PI_2).abs() < 1e-4, "angles {a} then {b}");
        }
    }

    #[test]
    fn descriptors_survive_a_90_degree_rotation() {
        let img = textured(240, 180, 1);
        let rotated = imageops::rotate90(&img);
        let a = detect_and_describe(&img, &OrbParams::default());
        let b = detect_and_describe(&rotated, &OrbParams::default());
        let h = img.height() as f32;
        // Level-0 keypoints found at the same (rotated) place in both images.
        let mut same_place = Vec::new();
        let mut unrelated = Vec::new();
        for (i, (ka, da)) in a.iter().enumerate().filter(|(_, (k, _))| k.level == 0) {
            let (bx, by) = (h - 1.0 - ka.y, ka.x);
            if let Some((_, db)) = b
                .iter()
                .find(|(kb, _)| kb.level == 0 && kb.x == bx && kb.y == by)
            {
                same_place.push(hamming(da, db));
                let other = &b[(i * 7 + 3) % b.len()];
                if other.0.x != bx || other.0.y != by {
                    unrelated.push(hamming(da, &other.1));
                }
            }
        }
        same_place.sort_unstable();
        unrelated.sort_unstable();
        assert!(
            same_place.len() >= 20,
            "only {} shared keypoints",
            same_place.len()
        );
        let median = |v: &[u32]| v[v.len() / 2];
        assert!(median(&same_place) <= 10, "same place: {same_place:?}");
        assert!(median(&unrelated) >= 80, "unrelated: {unrelated:?}");
    }

    #[test]
    fn flat_or_tiny_images_give_no_features() {
        let params = OrbParams::default();
        assert!(extract(&GrayImage::new(0, 0), &params).is_empty());
        assert!(extract(&GrayImage::new(30, 30), &params).is_empty());
        assert!(extract(&GrayImage::from_pixel(200, 150, Luma([128])), &params).is_empty());
        // A scale factor below 1 must not grow the pyramid: level 0 only.
        let shrinking = OrbParams {
            scale_factor: 0.5,
            ..OrbParams::default()
        };
        let kps = detect_and_describe(&textured(120, 90, 2), &shrinking);
        assert!(!kps.is_empty() && kps.iter().all(|(k, _)| k.level == 0));
    }

    #[test]
    fn quadtree_keeps_the_strongest_corner_of_each_cluster() {
        // Four tight clusters and four wanted: one survivor per cluster.
        let mut corners = Vec::new();
        for (i, (cx, cy)) in [(20, 20), (80, 20), (20, 80), (80, 80)]
            .into_iter()
            .enumerate()
        {
            for j in 0..5u32 {
                corners.push(Corner::new(cx + j, cy + j % 2, (10 * i as u32 + j) as f32));
            }
        }
        let bounds = Rect {
            x0: 0.0,
            x1: 100.0,
            y0: 0.0,
            y1: 100.0,
        };
        let mut kept = distribute_quadtree(&corners, bounds, 4);
        kept.sort_by(|a, b| a.score.total_cmp(&b.score));
        let scores: Vec<f32> = kept.iter().map(|c| c.score).collect();
        assert_eq!(scores, vec![4.0, 14.0, 24.0, 34.0]);
    }
}
