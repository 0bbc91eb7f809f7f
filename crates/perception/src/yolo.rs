//! Detections and instance masks from Ultralytics YOLO outputs.
//!
//! Two output layouts exist and both are read here, so that swapping the
//! exported model does not change the rest of the pipeline:
//!
//! - [`Layout::Anchors`] (YOLOv8/YOLO11 detect and segment): `output0` is
//!   `[1, 4 + nc + nm, A]`, channel-major: for anchor `a`, rows 0..4 hold
//!   `cx, cy, w, h`, rows `4..4 + nc` the (already sigmoid) class scores and
//!   the last `nm` rows the mask coefficients. Each anchor keeps its best
//!   class, as Ultralytics does without `multi_label`, and the candidates
//!   still need [`nms`].
//! - [`Layout::EndToEnd`] (NMS-free YOLOv10/YOLO26 exports): `output0` is
//!   `[1, N, 6 + nm]`, one row `x1, y1, x2, y2, score, class_id, coeffs…`
//!   per detection, already suppressed; class ids are floats and are rounded
//!   and bounds-checked.
//!
//! Boxes are in model-input pixels; mapping back to the image (letterbox
//! offset, scale) is the caller's. Segmentation models add `output1`, the
//! prototypes `[1, nm, mh, mw]`; an instance's mask is the sigmoid of its
//! coefficients times the prototypes, cropped to its box. Only the mask's
//! centroid and area are needed downstream, so [`mask_stats`] computes them
//! at prototype resolution instead of upsampling a full mask. Malformed
//! shapes are errors, malformed values (NaN boxes or scores, class ids out of
//! range) drop the detection; nothing panics on model output.

use crate::geometry::Rect;

/// Which output layout the model has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// `[1, 4 + nc + nm, A]`, needs NMS.
    Anchors,
    /// `[1, N, 6 + nm]`, NMS-free.
    EndToEnd,
}

/// One detected object.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Index of the best class in the model's class list.
    pub class_id: usize,
    /// That class's score.
    pub score: f32,
    /// Box in model-input pixels.
    pub rect: Rect,
    /// Mask coefficients (empty for detection-only models).
    pub mask_coeffs: Vec<f32>,
}

/// Errors of reading a YOLO output tensor.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum YoloError {
    /// The shape does not fit the layout, class count and mask count.
    #[error("YOLO output shape {got:?} does not match the expected {expected}; check the layout, class count and mask count")]
    Shape {
        /// The shape given.
        got: Vec<usize>,
        /// The shape expected, written out.
        expected: String,
    },
    /// The number of values is not the product of the shape.
    #[error("YOLO output has {got} values but its shape {shape:?} needs {expected}")]
    Length {
        /// The shape given.
        shape: Vec<usize>,
        /// Values the shape needs.
        expected: usize,
        /// Values given.
        got: usize,
    },
}

/// Decodes `output0` of shape `shape` into detections scoring above
/// `conf_threshold` (strictly, as Ultralytics). `num_masks` is 0 for
/// detection models, 32 for the usual segmentation models.
pub fn decode(
    output: &[f32],
    shape: &[usize],
    layout: Layout,
    num_classes: usize,
    num_masks: usize,
    conf_threshold: f32,
) -> Result<Vec<Detection>, YoloError> {
    let (width, expected) = match layout {
        Layout::Anchors => {
            let channels = 4usize.saturating_add(num_classes).saturating_add(num_masks);
            (channels, format!("[1, {channels}, anchors]"))
        }
        Layout::EndToEnd => {
            let columns = 6usize.saturating_add(num_masks);
            (columns, format!("[1, detections, {columns}]"))
        }
    };
    let shape_ok = match (layout, shape) {
        (Layout::Anchors, &[1, channels, _]) => channels == width,
        (Layout::EndToEnd, &[1, _, columns]) => columns == width,
        _ => false,
    };
    if !shape_ok {
        return Err(YoloError::Shape {
            got: shape.to_vec(),
            expected,
        });
    }
    let len = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
    if len != Some(output.len()) {
        return Err(YoloError::Length {
            shape: shape.to_vec(),
            expected: len.unwrap_or(usize::MAX),
            got: output.len(),
        });
    }
    Ok(match layout {
        Layout::Anchors => anchors(output, shape[2], num_classes, num_masks, conf_threshold),
        Layout::EndToEnd => end_to_end(output, width, num_classes, conf_threshold),
    })
}

fn anchors(output: &[f32], count: usize, nc: usize, nm: usize, conf: f32) -> Vec<Detection> {
    let row = |r: usize| &output[r * count..(r + 1) * count];
    // Best class per anchor, reading the channel-major tensor row by row.
    let mut best = vec![(0usize, f32::NEG_INFINITY); count];
    for class in 0..nc {
        for (b, &s) in best.iter_mut().zip(row(4 + class)) {
            if s > b.1 {
                *b = (class, s);
            }
        }
    }
    let at = |r: usize, a: usize| output[r * count + a];
    best.iter()
        .enumerate()
        .filter(|(_, &(_, score))| score > conf)
        .filter_map(|(a, &(class_id, score))| {
            let (cx, cy, w, h) = (at(0, a), at(1, a), at(2, a), at(3, a));
            let rect = Rect {
                x0: cx - w * 0.5,
                y0: cy - h * 0.5,
                x1: cx + w * 0.5,
                y1: cy + h * 0.5,
            };
            finite(&rect).then(|| Detection {
                class_id,
                score,
                rect,
                mask_coeffs: (0..nm).map(|m| at(4 + nc + m, a)).collect(),
            })
        })
        .collect()
}

fn end_to_end(output: &[f32], width: usize, nc: usize, conf: f32) -> Vec<Detection> {
    output
        .chunks_exact(width)
        .filter(|r| r[4] > conf)
        .filter_map(|r| {
            let class = r[5].round();
            if !(class >= 0.0 && class < nc as f32) {
                return None;
            }
            let rect = Rect {
                x0: r[0],
                y0: r[1],
                x1: r[2],
                y1: r[3],
            };
            finite(&rect).then(|| Detection {
                class_id: class as usize,
                score: r[4],
                rect,
                mask_coeffs: r[6..].to_vec(),
            })
        })
        .collect()
}

fn finite(r: &Rect) -> bool {
    [r.x0, r.y0, r.x1, r.y1].iter().all(|v| v.is_finite())
}

/// Class-aware greedy non-maximum suppression: highest score first, a
/// detection is dropped when it overlaps a kept one of the same class by an
/// IoU above `iou_threshold`; at most `max_detections` are kept.
pub fn nms(
    mut detections: Vec<Detection>,
    iou_threshold: f32,
    max_detections: usize,
) -> Vec<Detection> {
    detections.retain(|d| !d.score.is_nan());
    detections.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<Detection> = Vec::new();
    for d in detections {
        if kept.len() >= max_detections {
            break;
        }
        let suppressed = kept
            .iter()
            .any(|k| k.class_id == d.class_id && k.rect.iou(&d.rect) > iou_threshold);
        if !suppressed {
            kept.push(d);
        }
    }
    kept
}

/// Centroid and area of an instance mask, in model-input pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaskStats {
    /// `[x, y]`.
    pub centroid: [f32; 2],
    /// Pixels².
    pub area: f32,
}

/// Statistics of `det`'s mask: `sigmoid(coeffs · protos) > 0.5` at prototype
/// resolution, keeping only the prototype pixels whose centres lie in the
/// box. `protos` is `output1` without its batch axis, `proto_shape` is
/// `[nm, mh, mw]` and `input_size` the model input `[w, h]`; each prototype
/// pixel stands for `(w / mw) × (h / mh)` input pixels. `None` when the mask
/// is empty or the shapes do not fit.
pub fn mask_stats(
    protos: &[f32],
    proto_shape: [usize; 3],
    det: &Detection,
    input_size: [usize; 2],
) -> Option<MaskStats> {
    let [nm, mh, mw] = proto_shape;
    let [iw, ih] = input_size;
    if nm == 0 || mh == 0 || mw == 0 || iw == 0 || ih == 0 || det.mask_coeffs.len() != nm {
        return None;
    }
    let plane = mh.checked_mul(mw)?;
    if plane.checked_mul(nm)? != protos.len() {
        return None;
    }
    let (cell_w, cell_h) = (iw as f64 / mw as f64, ih as f64 / mh as f64);
    let crop = det.rect.scale((1.0 / cell_w) as f32, (1.0 / cell_h) as f32);
    if !finite(&crop) {
        return None;
    }
    // Pixel `j` (centre `j + 0.5`) is inside when `x0 <= j + 0.5 < x1`.
    let index = |v: f32, n: usize| (v - 0.5).ceil().clamp(0.0, n as f32) as usize;
    let (j0, j1) = (index(crop.x0, mw), index(crop.x1, mw));
    let (i0, i1) = (index(crop.y0, mh), index(crop.y1, mh));
    if j0 >= j1 || i0 >= i1 {
        return None;
    }
    // Logits over the crop, one prototype plane at a time (contiguous reads).
    let cols = j1 - j0;
    let mut logits = vec![0.0f32; (i1 - i0) * cols];
    for (k, &c) in det.mask_coeffs.iter().enumerate() {
        let proto = &protos[k * plane..(k + 1) * plane];
        for (i, out) in (i0..i1).zip(logits.chunks_exact_mut(cols)) {
            let src = &proto[i * mw + j0..i * mw + j1];
            for (l, &p) in out.iter_mut().zip(src) {
                *l += c * p;
            }
        }
    }
    let (mut count, mut sum_j, mut sum_i) = (0usize, 0.0f64, 0.0f64);
    for (i, row) in (i0..i1).zip(logits.chunks_exact(cols)) {
        for (j, &l) in (j0..j1).zip(row) {
            // sigmoid(l) > 0.5 exactly when l > 0.
            if l > 0.0 {
                count += 1;
                sum_j += j as f64;
                sum_i += i as f64;
            }
        }
    }
    if count == 0 {
        return None;
    }
    let n = count as f64;
    Some(MaskStats {
        centroid: [
            ((sum_j / n + 0.5) * cell_w) as f32,
            ((sum_i / n + 0.5) * cell_h) as f32,
        ],
        area: (n * cell_w * cell_h) as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Anchor-layout tensor from per-anchor columns.
    fn channel_major(columns: &[Vec<f32>]) -> (Vec<f32>, Vec<usize>) {
        let (a, c) = (columns.len(), columns[0].len());
        let mut out = vec![0.0; a * c];
        for (j, col) in columns.iter().enumerate() {
            for (r, &v) in col.iter().enumerate() {
                out[r * a + j] = v;
            }
        }
        (out, vec![1, c, a])
    }

    fn rect(x0: f32, y0: f32, x1: f32, y1: f32) -> Rect {
        Rect { x0, y0, x1, y1 }
    }

    #[test]
    fn anchors_decode_and_nms() {
        // nc = 2, nm = 0: cx, cy, w, h, s0, s1.
        let (out, shape) = channel_major(&[
            vec![20.0, 20.0, 10.0, 10.0, 0.9, 0.1],
            vec![21.0, 20.0, 10.0, 10.0, 0.8, 0.2], // same class, overlaps the first
            vec![20.0, 21.0, 10.0, 10.0, 0.1, 0.7], // other class, same place
            vec![60.0, 60.0, 8.0, 8.0, 0.2, 0.1],   // below threshold
        ]);
        let dets = decode(&out, &shape, Layout::Anchors, 2, 0, 0.25).unwrap();
        assert_eq!(dets.len(), 3);
        assert_eq!(dets[0].rect, rect(15.0, 15.0, 25.0, 25.0));
        assert_eq!((dets[2].class_id, dets[2].score), (1, 0.7));
        assert!(dets.iter().all(|d| d.mask_coeffs.is_empty()));
        let kept = nms(dets, 0.45, 100);
        let summary: Vec<(usize, f32)> = kept.iter().map(|d| (d.class_id, d.score)).collect();
        assert_eq!(summary, [(0, 0.9), (1, 0.7)]);
    }

    #[test]
    fn anchors_with_mask_coefficients() {
        // nc = 1, nm = 2.
        let (out, shape) = channel_major(&[
            vec![10.0, 10.0, 4.0, 6.0, 0.6, 0.5, -1.5],
            vec![30.0, 30.0, 4.0, 4.0, 0.1, 9.0, 9.0],
        ]);
        let dets = decode(&out, &shape, Layout::Anchors, 1, 2, 0.5).unwrap();
        assert_eq!(dets.len(), 1);
        assert_eq!(dets[0].rect, rect(8.0, 7.0, 12.0, 13.0));
        assert_eq!(dets[0].mask_coeffs, [0.5, -1.5]);
    }

    #[test]
    fn end_to_end_decode() {
        let rows: Vec<f32> = [
            [1.0, 2.0, 11.0, 12.0, 0.9, 1.000_01, 0.25],
            [5.0, 5.0, 9.0, 9.0, 0.8, 2.0, 0.0], // class out of range
            [5.0, 5.0, 9.0, 9.0, 0.8, -1.0, 0.0], // negative class
            [5.0, 5.0, 9.0, 9.0, 0.8, f32::NAN, 0.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], // padding
            [f32::NAN, 0.0, 1.0, 1.0, 0.9, 0.0, 0.0],
            [3.0, 3.0, 4.0, 4.0, 0.3, 0.4, 1.0], // class 0.4 → 0
        ]
        .concat();
        let dets = decode(&rows, &[1, 7, 7], Layout::EndToEnd, 2, 1, 0.25).unwrap();
        assert_eq!(dets.len(), 2);
        assert_eq!(dets[0].class_id, 1);
        assert_eq!(dets[0].rect, rect(1.0, 2.0, 11.0, 12.0));
        assert_eq!(dets[0].mask_coeffs, [0.25]);
        assert_eq!((dets[1].class_id, dets[1].score), (0, 0.3));
    }

    #[test]
    fn shape_mismatches_are_errors() {
        let out = vec![0.0; 6 * 4];
        let shape_err =
            |r: Result<Vec<Detection>, YoloError>| matches!(r, Err(YoloError::Shape { .. }));
        assert!(shape_err(decode(
            &out,
            &[1, 6, 4],
            Layout::Anchors,
            80,
            0,
            0.25
        )));
        assert!(shape_err(decode(
            &out,
            &[2, 6, 2],
            Layout::Anchors,
            2,
            0,
            0.25
        )));
        assert!(shape_err(decode(
            &out,
            &[6, 4],
            Layout::Anchors,
            2,
            0,
            0.25
        )));
        assert!(shape_err(decode(
            &out,
            &[1, 4, 6],
            Layout::EndToEnd,
            2,
            1,
            0.25
        )));
        assert!(shape_err(decode(
            &out,
            &[1, 6, 4],
            Layout::Anchors,
            usize::MAX,
            0,
            0.25
        )));
        assert_eq!(
            decode(&out, &[1, 6, 5], Layout::Anchors, 2, 0, 0.25),
            Err(YoloError::Length {
                shape: vec![1, 6, 5],
                expected: 30,
                got: 24
            })
        );
        assert!(matches!(
            decode(&out, &[1, 6, usize::MAX], Layout::Anchors, 2, 0, 0.25),
            Err(YoloError::Length { .. })
        ));
        assert_eq!(
            decode(&out, &[1, 6, 4], Layout::Anchors, 2, 0, 0.25),
            Ok(vec![])
        );
        assert_eq!(
            decode(&[], &[1, 0, 6], Layout::EndToEnd, 2, 0, 0.25),
            Ok(vec![])
        );
    }

    #[test]
    fn nms_orders_and_caps() {
        let det = |class_id, score, x: f32| Detection {
            class_id,
            score,
            rect: rect(x, 0.0, x + 10.0, 10.0),
            mask_coeffs: vec![],
        };
        let dets = vec![
            det(0, 0.5, 0.0),
            det(0, 0.7, 50.0),
            det(0, 0.9, 100.0),
            det(0, f32::NAN, 200.0),
        ];
        let kept = nms(dets.clone(), 0.5, 2);
        let scores: Vec<f32> = kept.iter().map(|d| d.score).collect();
        assert_eq!(scores, [0.9, 0.7]);
        assert!(nms(dets, 0.5, 0).is_empty());
        assert!(nms(vec![], 0.5, 10).is_empty());
    }

    /// Two prototypes on an 8 × 8 grid for a 32 × 32 input (4 × 4 pixels per
    /// cell): the first is +1 on rows 2..=4, columns 1..=3 and −1 elsewhere,
    /// the second is 1 everywhere.
    fn protos() -> Vec<f32> {
        let mut p = vec![-1.0; 2 * 64];
        for i in 2..=4 {
            for j in 1..=3 {
                p[i * 8 + j] = 1.0;
            }
        }
        p[64..].fill(1.0);
        p
    }

    fn seg(rect: Rect, coeffs: [f32; 2]) -> Detection {
        Detection {
            class_id: 0,
            score: 0.9,
            rect,
            mask_coeffs: coeffs.to_vec(),
        }
    }

    #[test]
    fn mask_of_a_known_rectangle() {
        // Logit 2 + 0.5 inside, −2 + 0.5 outside.
        let det = seg(rect(0.0, 0.0, 32.0, 32.0), [2.0, 0.5]);
        let stats = mask_stats(&protos(), [2, 8, 8], &det, [32, 32]).unwrap();
        // 9 cells of 16 px²; centre cell (2, 3) → ((2 + 0.5) · 4, (3 + 0.5) · 4).
        assert_eq!(stats.area, 144.0);
        assert_eq!(stats.centroid, [10.0, 14.0]);
    }

    #[test]
    fn mask_is_cropped_to_the_box() {
        // Box x in [0, 12) → cells 0..=2: mask columns 1 and 2 remain.
        let det = seg(rect(0.0, 0.0, 12.0, 32.0), [2.0, 0.5]);
        let stats = mask_stats(&protos(), [2, 8, 8], &det, [32, 32]).unwrap();
        assert_eq!(stats.area, 96.0);
        assert_eq!(stats.centroid, [8.0, 14.0]);
        // Non-square cells: 64 × 32 input → 8 × 4 px per cell.
        let det = seg(rect(0.0, 0.0, 64.0, 32.0), [2.0, 0.5]);
        let stats = mask_stats(&protos(), [2, 8, 8], &det, [64, 32]).unwrap();
        assert_eq!(stats.area, 9.0 * 32.0);
        assert_eq!(stats.centroid, [20.0, 14.0]);
    }

    #[test]
    fn empty_or_mismatched_masks() {
        let p = protos();
        let full = rect(0.0, 0.0, 32.0, 32.0);
        assert_eq!(
            mask_stats(&p, [2, 8, 8], &seg(full, [-1.0, -1.0]), [32, 32]),
            None
        );
        let outside = rect(20.0, 0.0, 32.0, 32.0);
        assert_eq!(
            mask_stats(&p, [2, 8, 8], &seg(outside, [2.0, 0.5]), [32, 32]),
            None
        );
        let nan = rect(f32::NAN, 0.0, 32.0, 32.0);
        assert_eq!(
            mask_stats(&p, [2, 8, 8], &seg(nan, [2.0, 0.5]), [32, 32]),
            None
        );
        let det = seg(full, [2.0, 0.5]);
        assert_eq!(mask_stats(&p, [2, 8, 7], &det, [32, 32]), None);
        assert_eq!(mask_stats(&p, [3, 8, 8], &det, [32, 32]), None);
        assert_eq!(mask_stats(&p, [2, 8, 8], &det, [0, 32]), None);
        assert_eq!(mask_stats(&p, [2, usize::MAX, 8], &det, [32, 32]), None);
    }

    proptest! {
        #[test]
        fn decode_never_panics(
            values in proptest::collection::vec(-2f32..2.0, 0..80),
            shape in proptest::collection::vec(0usize..12, 0..4),
            nc in 0usize..4,
            nm in 0usize..3,
            end_to_end in any::<bool>(),
        ) {
            let layout = if end_to_end { Layout::EndToEnd } else { Layout::Anchors };
            if let Ok(dets) = decode(&values, &shape, layout, nc, nm, 0.1) {
                for d in &dets {
                    prop_assert!(d.class_id < nc && d.score > 0.1);
                    prop_assert_eq!(d.mask_coeffs.len(), nm);
                }
                let kept = nms(dets, 0.5, 5);
                prop_assert!(kept.len() <= 5);
            }
        }

        #[test]
        fn mask_stats_never_panics(
            protos in proptest::collection::vec(-1f32..1.0, 0..50),
            shape in (0usize..3, 0usize..5, 0usize..5),
            coeffs in proptest::collection::vec(-1f32..1.0, 0..3),
            b in (-10f32..40.0, -10f32..40.0, -10f32..40.0, -10f32..40.0),
        ) {
            let det = Detection { class_id: 0, score: 1.0, rect: rect(b.0, b.1, b.2, b.3), mask_coeffs: coeffs };
            if let Some(s) = mask_stats(&protos, [shape.0, shape.1, shape.2], &det, [32, 24]) {
                prop_assert!(s.area > 0.0 && s.area <= 32.0 * 24.0);
                prop_assert!((0.0..=32.0).contains(&s.centroid[0]));
                prop_assert!((0.0..=24.0).contains(&s.centroid[1]));
            }
        }
    }
}
