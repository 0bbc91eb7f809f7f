//! A data set image as a method is given it: the file's own bytes, the
//! file degraded for a condition, or its grey pixels (`--grey`).
//!
//! Every method (HuMem-VPR in process, the service over gRPC, the ORB
//! baseline) reads its images through here, so that all of them see the
//! same pixels under a condition; it depends only on [`crate::degrade`].

use std::io::Cursor;
use std::path::Path;

use anyhow::Context;

use crate::degrade::{self, Degradation};
use humem_perception::image::{decode as image_decode, luma, EncodedImage, Encoding};
use humem_perception::ImageInput;

/// The bytes of an image, degraded (and re-encoded losslessly) if asked.
pub(crate) fn image_bytes(
    path: &Path,
    degradation: Option<&Degradation>,
) -> anyhow::Result<Vec<u8>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let Some(d) = degradation else {
        return Ok(bytes);
    };
    let image = image_decode(&EncodedImage::file(&bytes))
        .with_context(|| format!("decoding {}", path.display()))?;
    let degraded = degrade::apply(&image, d);
    let mut png = Vec::new();
    degraded.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)?;
    Ok(png)
}

/// The request image of a file: the file itself, or its grey pixels.
pub(crate) fn image_input(data: Vec<u8>, grey: bool) -> anyhow::Result<ImageInput> {
    if !grey {
        return Ok(ImageInput::file(data));
    }
    let rgb = image_decode(&EncodedImage::file(&data))?;
    Ok(ImageInput {
        encoding: Encoding::Gray8,
        data: rgb.pixels().map(|p| luma(p.0)).collect(),
        width: rgb.width(),
        height: rgb.height(),
        stride: 0,
    })
}
