//! Axis-aligned rectangles shared by the detectors' post-processing.
//!
//! Every detector here (DBNet text boxes, YOLO objects) ends in the same
//! thing: an axis-aligned box in some pixel frame that later gets scaled back
//! to the original image, clamped to it, and compared by overlap. One small
//! `Copy` type with those few operations keeps the post-processing modules
//! free of ad-hoc tuples. Coordinates are continuous pixel coordinates: pixel
//! `i` spans `[i, i + 1)`, so `x1`/`y1` are exclusive and `width = x1 - x0`.
//! Degenerate or inverted rectangles are allowed and simply have zero area.

/// An axis-aligned rectangle in pixel coordinates, `x1`/`y1` exclusive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    /// Left edge, inclusive.
    pub x0: f32,
    /// Top edge, inclusive.
    pub y0: f32,
    /// Right edge, exclusive.
    pub x1: f32,
    /// Bottom edge, exclusive.
    pub y1: f32,
}

impl Rect {
    /// `x1 - x0`, or 0 when inverted.
    pub fn width(&self) -> f32 {
        (self.x1 - self.x0).max(0.0)
    }

    /// `y1 - y0`, or 0 when inverted.
    pub fn height(&self) -> f32 {
        (self.y1 - self.y0).max(0.0)
    }

    /// Width times height.
    pub fn area(&self) -> f32 {
        self.width() * self.height()
    }

    /// The centre `[x, y]`.
    pub fn center(&self) -> [f32; 2] {
        [(self.x0 + self.x1) * 0.5, (self.y0 + self.y1) * 0.5]
    }

    /// Intersection over union, in [0, 1]; 0 when the union is empty.
    pub fn iou(&self, other: &Rect) -> f32 {
        let inter = Rect {
            x0: self.x0.max(other.x0),
            y0: self.y0.max(other.y0),
            x1: self.x1.min(other.x1),
            y1: self.y1.min(other.y1),
        }
        .area();
        let union = self.area() + other.area() - inter;
        if union > 0.0 {
            (inter / union).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// The rectangle with x coordinates multiplied by `sx` and y by `sy`
    /// (moving between pixel frames of different resolution).
    pub fn scale(&self, sx: f32, sy: f32) -> Rect {
        Rect {
            x0: self.x0 * sx,
            y0: self.y0 * sy,
            x1: self.x1 * sx,
            y1: self.y1 * sy,
        }
    }

    /// The rectangle with every coordinate clamped into `[0, w] × [0, h]`.
    pub fn clamp(&self, w: f32, h: f32) -> Rect {
        let (w, h) = (w.max(0.0), h.max(0.0));
        Rect {
            x0: self.x0.clamp(0.0, w),
            y0: self.y0.clamp(0.0, h),
            x1: self.x1.clamp(0.0, w),
            y1: self.y1.clamp(0.0, h),
        }
    }

    /// The rectangle grown by `d` on every side (shrunk when `d < 0`).
    pub fn expand(&self, d: f32) -> Rect {
        Rect {
            x0: self.x0 - d,
            y0: self.y0 - d,
            x1: self.x1 + d,
            y1: self.y1 + d,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn r(x0: f32, y0: f32, x1: f32, y1: f32) -> Rect {
        Rect { x0, y0, x1, y1 }
    }

    #[test]
    fn measures() {
        let a = r(1.0, 2.0, 5.0, 8.0);
        assert_eq!(a.width(), 4.0);
        assert_eq!(a.height(), 6.0);
        assert_eq!(a.area(), 24.0);
        assert_eq!(a.center(), [3.0, 5.0]);
        assert_eq!(r(5.0, 5.0, 1.0, 1.0).area(), 0.0);
    }

    #[test]
    fn iou_by_hand() {
        let a = r(0.0, 0.0, 4.0, 4.0);
        let b = r(2.0, 0.0, 6.0, 4.0);
        // Intersection 2×4 = 8, union 16 + 16 − 8 = 24.
        assert!((a.iou(&b) - 8.0 / 24.0).abs() < 1e-6);
        assert_eq!(a.iou(&a), 1.0);
        assert_eq!(a.iou(&r(10.0, 10.0, 12.0, 12.0)), 0.0);
        assert_eq!(r(1.0, 1.0, 1.0, 1.0).iou(&r(1.0, 1.0, 1.0, 1.0)), 0.0);
    }

    #[test]
    fn scale_clamp_expand() {
        let a = r(1.0, 2.0, 3.0, 4.0);
        assert_eq!(a.scale(2.0, 0.5), r(2.0, 1.0, 6.0, 2.0));
        assert_eq!(a.expand(1.5), r(-0.5, 0.5, 4.5, 5.5));
        assert_eq!(
            r(-3.0, -1.0, 12.0, 7.0).clamp(10.0, 5.0),
            r(0.0, 0.0, 10.0, 5.0)
        );
    }

    proptest! {
        #[test]
        fn iou_is_symmetric_and_bounded(
            a in (-50f32..50.0, -50f32..50.0, 0f32..40.0, 0f32..40.0),
            b in (-50f32..50.0, -50f32..50.0, 0f32..40.0, 0f32..40.0),
        ) {
            let a = r(a.0, a.1, a.0 + a.2, a.1 + a.3);
            let b = r(b.0, b.1, b.0 + b.2, b.1 + b.3);
            let (ab, ba) = (a.iou(&b), b.iou(&a));
            prop_assert!((0.0..=1.0).contains(&ab));
            prop_assert!((ab - ba).abs() < 1e-6);
        }
    }
}
