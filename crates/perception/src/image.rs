//! Camera images in: decoding to RGB and resizing to a model's input.
//!
//! Clients send JPEG or PNG files, or raw 8-bit frames as SLAM systems hold
//! them (gray for ORB-SLAM3's monocular and stereo inputs, BGR from OpenCV),
//! with an optional row stride. Everything becomes one RGB image; models
//! then take resized copies of it. JPEGs are decoded by libjpeg-turbo (the
//! `turbojpeg` crate; accurate integer IDCT, smooth chroma upsampling), the
//! decoder of Pillow, OpenCV and so of the pipelines the models were trained
//! and checked with: the `image` crate's pure-Rust decoder differs by up to 3
//! levels per pixel, enough to move the descriptor's cosine with the Python
//! reference to 0.998 and corridor's R@1 by 0.03 (see
//! `tests/e2e/fidelity.rs`). PNGs are the `image` crate's; resizing is
//! `fast_image_resize`'s (SIMD convolution).

use fast_image_resize as fir;
use image::{DynamicImage, RgbImage};

/// Smallest accepted side, in pixels.
pub const MIN_SIDE: u32 = 16;
/// Largest accepted side, in pixels.
pub const MAX_SIDE: u32 = 8192;

/// How the bytes of an image are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// JPEG or PNG, recognised from the bytes.
    Auto,
    /// A JPEG file.
    Jpeg,
    /// A PNG file.
    Png,
    /// Raw 8-bit grey, one byte per pixel.
    Gray8,
    /// Raw 8-bit RGB, three bytes per pixel in R, G, B order.
    Rgb8,
    /// Raw 8-bit BGR, three bytes per pixel in B, G, R order (OpenCV's).
    Bgr8,
}

impl Encoding {
    /// Bytes per pixel of a raw encoding.
    fn raw_channels(self) -> Option<usize> {
        match self {
            Encoding::Gray8 => Some(1),
            Encoding::Rgb8 | Encoding::Bgr8 => Some(3),
            _ => None,
        }
    }
}

/// An image as received.
#[derive(Debug, Clone, Copy)]
pub struct EncodedImage<'a> {
    /// How `data` is encoded.
    pub encoding: Encoding,
    /// The file's bytes, or the raw pixel rows.
    pub data: &'a [u8],
    /// Width in pixels; raw encodings only.
    pub width: u32,
    /// Height in pixels; raw encodings only.
    pub height: u32,
    /// Raw encodings only; 0 = tightly packed.
    pub stride: u32,
}

/// Why an image cannot be used. Messages name the request field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImageError {
    /// No bytes were sent.
    #[error("data: empty")]
    Empty,
    /// The bytes are neither JPEG nor PNG and no raw encoding was given.
    #[error("data: neither JPEG nor PNG; set encoding for raw pixels")]
    Unrecognised,
    /// The decoder rejected the file; the decoder's message.
    #[error("data: does not decode: {0}")]
    Decode(String),
    /// A side is outside [`MIN_SIDE`]..=[`MAX_SIDE`] pixels.
    #[error("width, height: {width}x{height} is outside {MIN_SIDE}..={MAX_SIDE} pixels per side")]
    Size {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// A raw image's row stride is shorter than one row of pixels.
    #[error("stride: {stride} is less than width x {channels} = {row} bytes")]
    Stride {
        /// The stride given, in bytes.
        stride: usize,
        /// Bytes per pixel of the encoding.
        channels: usize,
        /// Bytes in one row of pixels (width × channels).
        row: usize,
    },
    /// A raw image has fewer bytes than its size and stride need.
    #[error("data: {found} bytes, a {width}x{height} image with stride {stride} needs {needed}")]
    Short {
        /// Bytes received.
        found: usize,
        /// Bytes needed: every row but the last at the stride, plus one row.
        needed: usize,
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Row stride in bytes.
        stride: usize,
    },
}

impl<'a> EncodedImage<'a> {
    /// A JPEG or PNG file's bytes (the format is recognised).
    pub fn file(data: &'a [u8]) -> EncodedImage<'a> {
        EncodedImage {
            encoding: Encoding::Auto,
            data,
            width: 0,
            height: 0,
            stride: 0,
        }
    }
}

fn check_size(width: u32, height: u32) -> Result<(), ImageError> {
    let ok = |s| (MIN_SIDE..=MAX_SIDE).contains(&s);
    if ok(width) && ok(height) {
        Ok(())
    } else {
        Err(ImageError::Size { width, height })
    }
}

/// Decodes an image to RGB.
pub fn decode(image: &EncodedImage) -> Result<RgbImage, ImageError> {
    if image.data.is_empty() {
        return Err(ImageError::Empty);
    }
    if let Some(channels) = image.encoding.raw_channels() {
        return decode_raw(image, channels);
    }
    let format = match image.encoding {
        Encoding::Jpeg => image::ImageFormat::Jpeg,
        Encoding::Png => image::ImageFormat::Png,
        _ => match image::guess_format(image.data) {
            Ok(f @ (image::ImageFormat::Jpeg | image::ImageFormat::Png)) => f,
            _ => return Err(ImageError::Unrecognised),
        },
    };
    if format == image::ImageFormat::Jpeg {
        if let Some(rgb) = decode_jpeg(image.data)? {
            return Ok(rgb);
        }
    }
    let decoded = image::load_from_memory_with_format(image.data, format)
        .map_err(|e| ImageError::Decode(e.to_string()))?;
    check_size(decoded.width(), decoded.height())?;
    Ok(match decoded {
        DynamicImage::ImageRgb8(rgb) => rgb,
        other => other.to_rgb8(),
    })
}

/// A JPEG decoded by libjpeg-turbo, its size checked from the header first;
/// `None` for what libjpeg-turbo cannot turn into RGB (CMYK), left to the
/// `image` crate.
fn decode_jpeg(data: &[u8]) -> Result<Option<RgbImage>, ImageError> {
    let decode_error = |e: turbojpeg::Error| ImageError::Decode(e.to_string());
    let mut decompressor = turbojpeg::Decompressor::new().map_err(decode_error)?;
    let header = decompressor.read_header(data).map_err(decode_error)?;
    if header.colorspace == turbojpeg::Colorspace::CMYK
        || header.colorspace == turbojpeg::Colorspace::YCCK
    {
        return Ok(None);
    }
    let (width, height) = (header.width as u32, header.height as u32);
    check_size(width, height)?;
    let pitch = header.width * 3;
    let mut pixels = vec![0u8; pitch * header.height];
    let output = turbojpeg::Image {
        pixels: pixels.as_mut_slice(),
        width: header.width,
        pitch,
        height: header.height,
        format: turbojpeg::PixelFormat::RGB,
    };
    decompressor
        .decompress(data, output)
        .map_err(decode_error)?;
    Ok(Some(
        RgbImage::from_raw(width, height, pixels).expect("buffer has width x height x 3 bytes"),
    ))
}

fn decode_raw(image: &EncodedImage, channels: usize) -> Result<RgbImage, ImageError> {
    let (width, height) = (image.width, image.height);
    check_size(width, height)?;
    let row = width as usize * channels;
    let stride = if image.stride == 0 {
        row
    } else {
        image.stride as usize
    };
    if stride < row {
        return Err(ImageError::Stride {
            stride,
            channels,
            row,
        });
    }
    let needed = stride * (height as usize - 1) + row;
    if image.data.len() < needed {
        return Err(ImageError::Short {
            found: image.data.len(),
            needed,
            width,
            height,
            stride,
        });
    }
    let mut rgb = Vec::with_capacity(width as usize * height as usize * 3);
    for y in 0..height as usize {
        let line = &image.data[y * stride..y * stride + row];
        match image.encoding {
            Encoding::Gray8 => line.iter().for_each(|&g| rgb.extend_from_slice(&[g, g, g])),
            Encoding::Bgr8 => line
                .chunks_exact(3)
                .for_each(|p| rgb.extend_from_slice(&[p[2], p[1], p[0]])),
            _ => rgb.extend_from_slice(line),
        }
    }
    Ok(RgbImage::from_raw(width, height, rgb).expect("buffer has width x height x 3 bytes"))
}

/// ITU-R 601 luma in fixed point, rounded: Pillow's `convert("L")` and
/// OpenCV's `COLOR_RGB2GRAY`, so grey made here matches a grey camera's.
pub fn luma([r, g, b]: [u8; 3]) -> u8 {
    ((u32::from(r) * 19595 + u32::from(g) * 38470 + u32::from(b) * 7471 + 0x8000) >> 16) as u8
}

/// Stretches `image`'s contrast in place: the luma levels at the `low` and
/// `high` fractions of its histogram go to 0 and 255, every channel
/// scaled alike (hue kept). Leaves nearly flat images (span under 8
/// levels) alone, where stretching would only amplify noise.
pub fn stretch_contrast(image: &mut RgbImage, low: f32, high: f32) {
    let mut histogram = [0u32; 256];
    for p in image.pixels() {
        histogram[usize::from(luma(p.0))] += 1;
    }
    let total = image.width() as f32 * image.height() as f32;
    let level_at = |fraction: f32| {
        let target = (fraction * total).max(0.0);
        let mut seen = 0.0;
        for (level, &count) in histogram.iter().enumerate() {
            seen += count as f32;
            if seen > target {
                return level as f32;
            }
        }
        255.0
    };
    let (lo, hi) = (level_at(low), level_at(high));
    if hi - lo < 8.0 {
        return;
    }
    let gain = 255.0 / (hi - lo);
    for p in image.pixels_mut() {
        for c in &mut p.0 {
            *c = ((f32::from(*c) - lo) * gain).round().clamp(0.0, 255.0) as u8;
        }
    }
}

/// `image` resized to `width` x `height` (bilinear, aspect ratio not kept).
pub fn resize(image: &RgbImage, width: u32, height: u32) -> RgbImage {
    if image.width() == width && image.height() == height {
        return image.clone();
    }
    let src = fir::images::ImageRef::new(
        image.width(),
        image.height(),
        image.as_raw(),
        fir::PixelType::U8x3,
    )
    .expect("an RgbImage is a valid U8x3 buffer");
    let mut dst = fir::images::Image::new(width, height, fir::PixelType::U8x3);
    let options = fir::ResizeOptions::new()
        .resize_alg(fir::ResizeAlg::Convolution(fir::FilterType::Bilinear));
    fir::Resizer::new()
        .resize(&src, &mut dst, &options)
        .expect("source and destination are both U8x3");
    RgbImage::from_raw(width, height, dst.into_vec()).expect("resized buffer has the right size")
}

/// Channel order of a model's input planes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channels {
    /// Red, green, blue.
    Rgb,
    /// PaddleOCR's models were trained on OpenCV's BGR images.
    Bgr,
}

/// Appends `image` as planar CHW floats, `(v / 255 − mean[c]) / std[c]` for
/// the c-th plane in `order`: the input layout of the configured CNNs.
pub fn append_chw(
    image: &RgbImage,
    order: Channels,
    mean: [f32; 3],
    std: [f32; 3],
    out: &mut Vec<f32>,
) {
    let pixels = image.as_raw();
    for (plane, (m, s)) in mean.into_iter().zip(std).enumerate() {
        let source = match order {
            Channels::Rgb => plane,
            Channels::Bgr => 2 - plane,
        };
        out.extend(
            pixels[source..]
                .iter()
                .step_by(3)
                .map(|&v| (f32::from(v) / 255.0 - m) / s),
        );
    }
}

/// The JPEG and PNG files of a folder, sorted by name (so their position is
/// their index in a sequence). An empty folder is an error (`NotFound`),
/// since every caller wants at least one image.
pub fn image_files(dir: &std::path::Path) -> std::io::Result<Vec<std::path::PathBuf>> {
    let mut paths: Vec<std::path::PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            matches!(
                p.extension()
                    .and_then(|e| e.to_str())
                    .map(str::to_ascii_lowercase)
                    .as_deref(),
                Some("jpg" | "jpeg" | "png")
            )
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "no JPEG or PNG images",
        ));
    }
    Ok(paths)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contrast_is_stretched_to_the_full_range() {
        // A dim two-level image (40 and 80) becomes black and white; hue is
        // kept because every channel is scaled alike.
        let mut image = RgbImage::from_fn(10, 10, |x, _| {
            if x < 5 {
                image::Rgb([40, 40, 40])
            } else {
                image::Rgb([80, 80, 80])
            }
        });
        stretch_contrast(&mut image, 0.02, 0.98);
        assert_eq!(image.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(image.get_pixel(9, 9).0, [255, 255, 255]);
        // A flat image is left alone.
        let mut flat = RgbImage::from_pixel(4, 4, image::Rgb([90, 92, 94]));
        stretch_contrast(&mut flat, 0.02, 0.98);
        assert_eq!(flat.get_pixel(0, 0).0, [90, 92, 94]);
    }

    fn raw(
        encoding: Encoding,
        data: &[u8],
        width: u32,
        height: u32,
        stride: u32,
    ) -> Result<RgbImage, ImageError> {
        decode(&EncodedImage {
            encoding,
            data,
            width,
            height,
            stride,
        })
    }

    #[test]
    fn raw_gray_bgr_and_rgb_with_stride() {
        // 16x16 gray with 4 bytes of padding per row.
        let mut data = Vec::new();
        for y in 0..16u8 {
            data.extend((0..16u8).map(|x| x + 16 * y));
            data.extend([0xAA; 4]);
        }
        let img = raw(Encoding::Gray8, &data, 16, 16, 20).unwrap();
        assert_eq!(img.get_pixel(3, 2).0, [35, 35, 35]);

        let bgr: Vec<u8> = (0..16 * 16).flat_map(|_| [1u8, 2, 3]).collect();
        assert_eq!(
            raw(Encoding::Bgr8, &bgr, 16, 16, 0)
                .unwrap()
                .get_pixel(5, 5)
                .0,
            [3, 2, 1]
        );
        assert_eq!(
            raw(Encoding::Rgb8, &bgr, 16, 16, 0)
                .unwrap()
                .get_pixel(5, 5)
                .0,
            [1, 2, 3]
        );
    }

    #[test]
    fn bad_raw_images_are_explained() {
        let data = vec![0u8; 16 * 16];
        assert_eq!(
            raw(Encoding::Gray8, &data, 16, 17, 0),
            Err(ImageError::Short {
                found: 256,
                needed: 272,
                width: 16,
                height: 17,
                stride: 16
            })
        );
        assert!(matches!(
            raw(Encoding::Gray8, &data, 8, 32, 0),
            Err(ImageError::Size { .. })
        ));
        assert!(matches!(
            raw(Encoding::Rgb8, &data, 16, 16, 20),
            Err(ImageError::Stride { .. })
        ));
        assert_eq!(raw(Encoding::Auto, &[], 0, 0, 0), Err(ImageError::Empty));
        assert_eq!(
            raw(Encoding::Auto, b"not an image", 0, 0, 0),
            Err(ImageError::Unrecognised)
        );
        assert!(matches!(
            raw(Encoding::Jpeg, b"\xff\xd8junk", 0, 0, 0),
            Err(ImageError::Decode(_))
        ));
    }

    #[test]
    fn png_round_trip_and_detection() {
        let mut img = RgbImage::new(20, 18);
        img.put_pixel(4, 7, image::Rgb([200, 10, 30]));
        let mut png = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let back = raw(Encoding::Auto, &png, 0, 0, 0).unwrap();
        assert_eq!(back, img);
    }

    fn jpeg(image: DynamicImage) -> Vec<u8> {
        let mut data = Vec::new();
        image
            .write_to(
                &mut std::io::Cursor::new(&mut data),
                image::ImageFormat::Jpeg,
            )
            .unwrap();
        data
    }

    #[test]
    fn jpegs_decode_through_libjpeg_turbo_in_colour_and_grey() {
        let colour = RgbImage::from_fn(64, 48, |x, y| {
            image::Rgb([(4 * x) as u8, (5 * y) as u8, 90])
        });
        let back = raw(
            Encoding::Auto,
            &jpeg(DynamicImage::ImageRgb8(colour.clone())),
            0,
            0,
            0,
        )
        .unwrap();
        assert_eq!(back.dimensions(), (64, 48));
        let worst = back
            .as_raw()
            .iter()
            .zip(colour.as_raw())
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(worst <= 12, "a smooth gradient survives JPEG: {worst}");

        let grey = image::GrayImage::from_fn(32, 32, |x, y| image::Luma([(3 * x + 4 * y) as u8]));
        let back = raw(
            Encoding::Jpeg,
            &jpeg(DynamicImage::ImageLuma8(grey)),
            0,
            0,
            0,
        )
        .unwrap();
        assert!(back.pixels().all(|p| p.0[0] == p.0[1] && p.0[1] == p.0[2]));

        // Too small for the service, refused from the header.
        let tiny = jpeg(DynamicImage::ImageRgb8(RgbImage::new(8, 8)));
        assert_eq!(
            raw(Encoding::Auto, &tiny, 0, 0, 0),
            Err(ImageError::Size {
                width: 8,
                height: 8
            })
        );
    }

    #[test]
    fn luma_is_pillows() {
        assert_eq!(luma([255, 255, 255]), 255);
        assert_eq!(luma([0, 0, 0]), 0);
        // 0.299 × 200 + 0.587 × 100 + 0.114 × 50 = 124.2
        assert_eq!(luma([200, 100, 50]), 124);
    }

    #[test]
    fn resize_and_normalise() {
        let img = RgbImage::from_pixel(32, 32, image::Rgb([255, 0, 51]));
        let small = resize(&img, 16, 8);
        assert_eq!(small.dimensions(), (16, 8));
        assert_eq!(small.get_pixel(3, 3).0, [255, 0, 51]);
        let mut out = Vec::new();
        append_chw(
            &small,
            Channels::Rgb,
            [0.5, 0.0, 0.0],
            [0.5, 1.0, 0.2],
            &mut out,
        );
        assert_eq!(out.len(), 3 * 16 * 8);
        // (1 - 0.5) / 0.5 = 1 ; 0 ; (0.2 - 0) / 0.2 = 1
        assert_eq!((out[0], out[128], out[256]), (1.0, 0.0, 1.0));
        // BGR: blue first: (0.2 - 0) / 1 = 0.2, green 0, red (1 - 0) / 0.5 = 2.
        out.clear();
        append_chw(&small, Channels::Bgr, [0.0; 3], [1.0, 1.0, 0.5], &mut out);
        assert!((out[0] - 0.2).abs() < 1e-6 && out[128] == 0.0 && out[256] == 2.0);
    }

    /// Structured fuzzing of image decoding (stable Rust, proptest): real
    /// JPEG and PNG files with bytes flipped, inserted, deleted or cut
    /// short, and raw pixel buffers of any declared size and stride.
    /// Decoding never panics: it returns an image of a size within the
    /// limits, or an error. Longer runs: `PROPTEST_CASES=100000 cargo test
    /// --release -p humem-perception fuzz`.
    mod fuzz {
        use super::*;
        use proptest::prelude::*;

        fn files() -> Vec<Vec<u8>> {
            let picture = RgbImage::from_fn(40, 30, |x, y| {
                image::Rgb([(6 * x) as u8, (8 * y) as u8, ((x * y) % 256) as u8])
            });
            let mut png = Vec::new();
            picture
                .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .unwrap();
            let grey = DynamicImage::ImageRgb8(picture.clone()).to_luma8();
            vec![
                jpeg(DynamicImage::ImageRgb8(picture)),
                jpeg(DynamicImage::ImageLuma8(grey)),
                png,
            ]
        }

        fn check(result: Result<RgbImage, ImageError>) {
            if let Ok(image) = result {
                assert!((MIN_SIDE..=MAX_SIDE).contains(&image.width()));
                assert!((MIN_SIDE..=MAX_SIDE).contains(&image.height()));
            }
        }

        proptest! {
            #[test]
            fn fuzz_mutated_files_decode_or_fail_cleanly(
                file in 0usize..3,
                edits in prop::collection::vec((0u8..4, any::<usize>(), any::<u8>()), 1..6),
                encoding in prop::sample::select(vec![Encoding::Auto, Encoding::Jpeg, Encoding::Png]),
            ) {
                let mut data = files().swap_remove(file);
                for (kind, at, byte) in edits {
                    let n = data.len();
                    match kind {
                        0 if n > 0 => data[at % n] ^= byte | 1,
                        1 => data.insert(at % (n + 1), byte),
                        2 if n > 0 => {
                            data.remove(at % n);
                        }
                        _ => data.truncate(at % (n + 1)),
                    }
                }
                check(raw(encoding, &data, 0, 0, 0));
            }

            #[test]
            fn fuzz_raw_buffers_of_any_declared_shape_decode_or_fail_cleanly(
                encoding in prop::sample::select(vec![Encoding::Gray8, Encoding::Rgb8, Encoding::Bgr8]),
                width in prop_oneof![0u32..80, any::<u32>()],
                height in prop_oneof![0u32..80, any::<u32>()],
                stride in prop_oneof![Just(0u32), 0u32..300, any::<u32>()],
                len in 0usize..20_000,
            ) {
                let data = vec![7u8; len];
                check(raw(encoding, &data, width, height, stride));
            }
        }
    }
}
