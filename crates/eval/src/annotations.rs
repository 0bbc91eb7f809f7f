//! Ground-truth objects in place of a detector (`humem eval --objects
//! annotations`), to measure the object and text layers on their own.
//!
//! No object detector ships in a package registry, so with the default models
//! OSRL and OGTL only see OCR text regions as `sign` objects. Data sets that
//! carry instance masks (town-dev: `<folder>_objects/NNNNNN.png`, 16-bit
//! instance ids, and an `objects.json` naming each id's class) let the
//! evaluation put the true objects where a detector's would go: one object
//! per instance, confidence 1, its mask's centroid and area. The text stays
//! what OCR read, grounded as the service grounds it: a text region belongs
//! to the instance under its centre, and text on no instance is dropped. So
//! the layers are checked with perfect objects and real text.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use image::{ImageBuffer, Luma};

use humem_core::keyframe::{Features, ObjectObservation};

/// Ground surfaces are not objects a detector of static landmarks reports.
const SURFACES: &[&str] = &["road", "sidewalk"];

/// Instances smaller than this many pixels are too small to detect.
const MIN_PIXELS: u32 = 30;

/// A 16-bit instance-id mask.
pub type InstanceMask = ImageBuffer<Luma<u16>, Vec<u16>>;

/// Instance id → what the object is, from `objects.json`.
#[derive(Debug, Clone)]
pub struct Catalog {
    /// Each instance id's object.
    pub objects: HashMap<u16, CatalogObject>,
}

/// One object of `objects.json`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct CatalogObject {
    /// The object's class, as a detector would name it (`shop_sign`, `pole`).
    pub class: String,
    /// The text it carries (signs, billboards), if any.
    #[serde(default)]
    pub text: Option<String>,
    /// Approximate centre in the world frame, metres, if given.
    #[serde(default)]
    pub position: Option<[f64; 3]>,
}

impl Catalog {
    /// Reads `objects.json` from the data set folder or its parent.
    pub fn find(dataset: &Path) -> anyhow::Result<Catalog> {
        let path = [
            dataset.join("objects.json"),
            dataset.join("../objects.json"),
        ]
        .into_iter()
        .find(|p| p.is_file())
        .with_context(|| format!("no objects.json in {} or its parent", dataset.display()))?;
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("reading {}", path.display()))
    }

    /// Parses `{"objects": {"<id>": {"class": "...", "text": ...,
    /// "position": [x, y, z]}, ...}}` (text and position optional).
    pub fn parse(text: &str) -> anyhow::Result<Catalog> {
        #[derive(serde::Deserialize)]
        struct File {
            objects: BTreeMap<String, CatalogObject>,
        }
        let file: File = serde_json::from_str(text)?;
        let mut objects = HashMap::new();
        for (id, entry) in file.objects {
            let id: u16 = id
                .parse()
                .with_context(|| format!("object id {id:?} is not a 16-bit number"))?;
            objects.insert(id, entry);
        }
        Ok(Catalog { objects })
    }
}

/// The mask of an image: `<dir>_objects/<stem>.png` beside `<dir>/<image>`.
pub fn mask_path(image: &Path) -> Option<PathBuf> {
    let dir = image.parent()?;
    let folder = dir.file_name()?.to_str()?;
    let stem = image.file_stem()?.to_str()?;
    Some(
        dir.parent()?
            .join(format!("{folder}_objects"))
            .join(format!("{stem}.png")),
    )
}

/// Reads the mask of an image.
pub fn read_mask(image: &Path) -> anyhow::Result<InstanceMask> {
    let path = mask_path(image).with_context(|| format!("no mask path for {}", image.display()))?;
    let decoded = image::open(&path).with_context(|| format!("reading {}", path.display()))?;
    match decoded {
        image::DynamicImage::ImageLuma16(mask) => Ok(mask),
        other => bail!(
            "{}: instance masks are 16-bit gray, not {:?}",
            path.display(),
            other.color()
        ),
    }
}

/// Replaces the detector's objects of `features` with the mask's instances,
/// moving the OCR text onto the instance under each text region's centre.
pub fn apply(features: &mut Features, mask: &InstanceMask, catalog: &Catalog) {
    let (w, h) = mask.dimensions();
    // Pixel count and coordinate sums per instance.
    let mut stats: BTreeMap<u16, (u32, f64, f64)> = BTreeMap::new();
    for (x, y, id) in mask.enumerate_pixels() {
        let id = id.0[0];
        if id == 0 {
            continue;
        }
        let s = stats.entry(id).or_default();
        s.0 += 1;
        s.1 += x as f64 + 0.5;
        s.2 += y as f64 + 0.5;
    }
    let mut objects: Vec<ObjectObservation> = Vec::new();
    let mut slot: HashMap<u16, usize> = HashMap::new();
    for (id, (pixels, sx, sy)) in stats {
        let Some(class) = catalog.objects.get(&id).map(|o| &o.class) else {
            continue;
        };
        if pixels < MIN_PIXELS || SURFACES.contains(&class.as_str()) {
            continue;
        }
        slot.insert(id, objects.len());
        objects.push(ObjectObservation {
            class_name: class.clone(),
            confidence: 1.0,
            centroid: [
                (sx / pixels as f64 / w as f64) as f32,
                (sy / pixels as f64 / h as f64) as f32,
            ],
            area: pixels as f32 / (w * h) as f32,
            texts: Vec::new(),
        });
    }
    for read in std::mem::take(&mut features.objects) {
        let x = ((read.centroid[0] * w as f32) as u32).min(w.saturating_sub(1));
        let y = ((read.centroid[1] * h as f32) as u32).min(h.saturating_sub(1));
        if let Some(&i) = slot.get(&mask.get_pixel(x, y).0[0]) {
            objects[i].texts.extend(read.texts);
        }
    }
    features.objects = objects;
}

#[cfg(test)]
mod tests {
    use super::*;
    use humem_core::keyframe::TextObservation;

    fn catalog() -> Catalog {
        Catalog::parse(
            r#"{"background_id": 0, "objects": {
                "1": {"class": "road", "text": null},
                "7": {"class": "shop_sign", "text": "ACME"},
                "9": {"class": "pole", "text": null}}}"#,
        )
        .unwrap()
    }

    fn text_region(x: f32, y: f32, text: &str) -> ObjectObservation {
        ObjectObservation {
            class_name: "sign".into(),
            confidence: 0.9,
            centroid: [x, y],
            area: 0.01,
            texts: vec![TextObservation {
                text: text.into(),
                confidence: 0.8,
            }],
        }
    }

    #[test]
    fn instances_become_objects_and_text_moves_onto_them() {
        // 20x10 image: road everywhere, a 10x4 sign at x 0..10, y 0..4, a
        // 2x10 pole at x 18..20 (20 pixels: too small), one unknown id.
        let mut mask = InstanceMask::from_pixel(20, 10, Luma([1]));
        for y in 0..4 {
            for x in 0..10 {
                mask.put_pixel(x, y, Luma([7]));
            }
        }
        for y in 0..10 {
            for x in 18..20 {
                mask.put_pixel(x, y, Luma([9]));
            }
        }
        mask.put_pixel(15, 9, Luma([42]));
        let mut features = Features {
            objects: vec![
                text_region(0.25, 0.2, "ACME BAKERY"), // on the sign
                text_region(0.7, 0.8, "STRAY"),        // on the road: dropped
            ],
            ..Default::default()
        };
        apply(&mut features, &mask, &catalog());
        assert_eq!(features.objects.len(), 1, "{:?}", features.objects);
        let sign = &features.objects[0];
        assert_eq!(sign.class_name, "shop_sign");
        assert_eq!(sign.confidence, 1.0);
        // Centroid (5, 2) of 20x10; area 40 / 200.
        assert_eq!(sign.centroid, [0.25, 0.2]);
        assert_eq!(sign.area, 0.2);
        assert_eq!(sign.texts.len(), 1);
        assert_eq!(sign.texts[0].text, "ACME BAKERY");
    }

    #[test]
    fn mask_path_sits_beside_the_image_folder() {
        assert_eq!(
            mask_path(Path::new("/d/town/query/000012.jpg")).unwrap(),
            PathBuf::from("/d/town/query_objects/000012.png")
        );
    }

    #[test]
    fn bad_catalogs_are_refused() {
        assert!(Catalog::parse(r#"{"objects": {"x": {"class": "pole"}}}"#).is_err());
        assert!(Catalog::parse(r#"{"objects": {"70000": {"class": "pole"}}}"#).is_err());
        assert!(Catalog::parse("[]").is_err());
    }
}
