//! `humem bench perception`: what each model costs a core per keyframe in
//! fp32 and int8, how long each takes per batch size, and what batching
//! gains when many clients send images at once, measured against unbatched
//! inference in the same run, on real images.
//!
//! Part 0 runs each model alone on one intra-op thread, batch 1, at both
//! precisions, and reports the process's CPU time per call (user and
//! system, `getrusage`): the core time a keyframe takes from the SLAM
//! process beside it, which wall time on a busy machine does not show.
//! Part 0b sends the images in order through the whole pipeline on one
//! thread and reports the same per keyframe, at fp32, at the configured
//! precisions, and with objects carried over between similar keyframes.
//! Part 1 calls each model directly (no queue) with batches of 1, 4 and 8
//! inputs, and text detection at the camera's aspect ratio against the
//! fixed 640x480 letterbox it replaced. Part 2 runs the whole perception pipeline for concurrent
//! clients twice, once with batching off (`max_batch = 1`) and once with
//! the configured batching, and reports the throughput ratio. Part 3 breaks
//! the batched pipeline down by stage.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};

use humem_perception::batcher::BatchModel;
use humem_perception::config::{OcrConfig, PerceptionConfig, Precision};
use humem_perception::geometry::Rect;
use humem_perception::image::{self as img, EncodedImage, Encoding};
use humem_perception::model::{ImageModel, Planes};
use humem_perception::ocr::{self, canvas, OcrModels};
use humem_perception::reuse::ReuseConfig;
use humem_perception::runtime::SessionOptions;
use humem_perception::{runtime, ImageInput, Perception};
use humem_server::config::Config;

/// Options of `humem bench perception`.
#[derive(Debug, Clone, clap::Args)]
pub struct PerceptionBench {
    /// Folder of JPEG/PNG images (default: ../shared/datasets/rtabmap-loop/sequence).
    #[arg(long)]
    pub images: Option<PathBuf>,
    /// Concurrent clients in part 2.
    #[arg(long, default_value_t = 8)]
    pub clients: usize,
    /// Images each client sends in part 2.
    #[arg(long, default_value_t = 12)]
    pub requests: usize,
    /// Timed runs per model and batch size in part 1.
    #[arg(long, default_value_t = 10)]
    pub repeats: usize,
    /// `max_batch` of the batched run in part 2.
    #[arg(long, default_value_t = 8)]
    pub batch: usize,
}

/// Mean and 95th percentile, in milliseconds (the harness's one latency
/// summary, [`crate::metrics::latency`]).
fn summary(samples: &[Duration]) -> (f64, f64) {
    let stats = crate::metrics::latency(samples);
    (stats.mean_ms, stats.p95_ms)
}

fn load_images(dir: &Path) -> anyhow::Result<Vec<Vec<u8>>> {
    let mut paths = crate::dataset::image_paths(dir)?;
    paths.truncate(32);
    paths
        .iter()
        .map(|p| std::fs::read(p).with_context(|| format!("reading {}", p.display())))
        .collect()
}

fn decode(bytes: &[u8]) -> anyhow::Result<image::RgbImage> {
    Ok(img::decode(&EncodedImage {
        encoding: Encoding::Auto,
        data: bytes,
        width: 0,
        height: 0,
        stride: 0,
    })?)
}

/// Times `run` on batches of 1, 4 and 8 inputs made by `input`.
fn time_model<M: BatchModel>(
    name: &str,
    model: &mut M,
    input: &dyn Fn(usize) -> M::Input,
    repeats: usize,
) -> anyhow::Result<()> {
    let mut one = Duration::ZERO;
    for batch in [1usize, 4, 8] {
        let make = || (0..batch).map(input).collect::<Vec<_>>();
        for _ in 0..2 {
            model.run(make())?;
        }
        let mut samples = Vec::with_capacity(repeats);
        for _ in 0..repeats {
            let inputs = make();
            let started = Instant::now();
            model.run(inputs)?;
            samples.push(started.elapsed());
        }
        let (mean, p95) = summary(&samples);
        let per_item = mean / batch as f64;
        if batch == 1 {
            one = Duration::from_secs_f64(mean / 1e3);
        }
        let speedup = one.as_secs_f64() * 1e3 / per_item;
        println!("{name:<18} {batch:>5} {mean:>10.1} {p95:>10.1} {per_item:>12.2} {speedup:>9.2}x");
    }
    Ok(())
}

/// The whole of `image` as a region.
fn whole(image: &image::RgbImage) -> Rect {
    Rect {
        x0: 0.0,
        y0: 0.0,
        x1: image.width() as f32,
        y1: image.height() as f32,
    }
}

/// Text detection per image at the camera's aspect ratio (`after`: the
/// inputs at the configured long side) against the fixed 640x480 letterbox
/// it replaced, one image at a time, alternating, in this run.
fn compare_detection_shapes(
    detector: &mut ImageModel,
    decoded: &[image::RgbImage],
    after: &[Planes],
    config: &OcrConfig,
    repeats: usize,
) -> anyhow::Result<()> {
    const BEFORE: [usize; 2] = [640, 480];
    let letterboxed = |image: &image::RgbImage| {
        let long = (BEFORE[0] as f32 / image.width() as f32)
            .min(BEFORE[1] as f32 / image.height() as f32)
            * image.width().max(image.height()) as f32;
        let (planes, _) = canvas::detector_input(image, whole(image), long.round() as u32);
        canvas::padded(&planes, BEFORE[0], BEFORE[1])
    };
    let before: Vec<Planes> = decoded.iter().map(letterboxed).collect();
    let (mut t_before, mut t_after) = (Vec::new(), Vec::new());
    for r in 0..repeats.max(1) * 2 {
        for (set, samples) in [(&before[..], &mut t_before), (after, &mut t_after)] {
            let input = set[r % set.len()].clone();
            let started = Instant::now();
            detector.run(vec![input])?;
            if r >= 2 {
                samples.push(started.elapsed());
            }
        }
    }
    let (b, _) = summary(&t_before);
    let (a, _) = summary(&t_after);
    let shape = |p: &Planes| format!("{}x{}", p.width, p.height);
    println!(
        "ocr detection per image: {} letterbox (before) {b:.1} ms, {} at long side {} {a:.1} ms: {:.2}x",
        shape(&before[0]),
        shape(&after[0]),
        config.detector_long_side,
        a / b
    );
    Ok(())
}

/// Runs perception for `clients` concurrent clients; returns the wall time
/// and every request's latency and stage timings.
async fn drive(
    perception: &Perception,
    images: &Arc<Vec<Vec<u8>>>,
    clients: usize,
    requests: usize,
) -> anyhow::Result<(Duration, Vec<Duration>, Vec<Vec<(&'static str, Duration)>>)> {
    let started = Instant::now();
    let tasks: Vec<_> = (0..clients)
        .map(|c| {
            let perception = perception.clone();
            let images = images.clone();
            tokio::spawn(async move {
                let mut out = Vec::new();
                for r in 0..requests {
                    let data = images[(c * requests + r) % images.len()].clone();
                    let sent = Instant::now();
                    let extracted = perception.extract(ImageInput::file(data)).await?;
                    out.push((sent.elapsed(), extracted.timings));
                }
                Ok::<_, anyhow::Error>(out)
            })
        })
        .collect();
    let mut latencies = Vec::new();
    let mut timings = Vec::new();
    for task in tasks {
        for (latency, stages) in task.await?? {
            latencies.push(latency);
            timings.push(stages);
        }
    }
    Ok((started.elapsed(), latencies, timings))
}

/// `humem bench perception`.
pub async fn perception(config: Config, args: PerceptionBench) -> anyhow::Result<()> {
    let dir = images_dir(args.images.clone())?;
    let images = Arc::new(load_images(&dir)?);
    let decoded: Vec<image::RgbImage> = images
        .iter()
        .map(|b| decode(b))
        .collect::<anyhow::Result<_>>()?;
    let p = &config.perception;
    println!(
        "humem bench perception: {} images from {}, provider {:?}, {} intra-op threads per model",
        images.len(),
        dir.display(),
        p.provider,
        p.session_options().intra_threads
    );
    core_time(p, &decoded, args.repeats)?;
    stream_core_time(&config, &images).await?;
    models_alone(p, &decoded, args.repeats)?;
    let batched_timings = pipeline_under_load(&config, &images, &args).await?;
    stage_table(&batched_timings);
    Ok(())
}

/// The images folder: `--images`, or the rtabmap-loop sequence of the
/// shared data sets.
fn images_dir(images: Option<PathBuf>) -> anyhow::Result<PathBuf> {
    Ok(match images {
        Some(dir) => dir,
        None => {
            let default = PathBuf::from("../shared/datasets/rtabmap-loop/sequence");
            if !default.is_dir() {
                bail!(
                    "no images: pass --images DIR (the default {} does not exist)",
                    default.display()
                );
            }
            default
        }
    })
}

/// Mean core milliseconds per call of `model` on batches of one input
/// made by `input`, after two warm-up calls.
fn core_ms<M: BatchModel>(
    model: &mut M,
    input: &dyn Fn(usize) -> M::Input,
    repeats: usize,
) -> anyhow::Result<f64> {
    for i in 0..2 {
        model.run(vec![input(i)])?;
    }
    let started = humem_perception::cpu::process_cpu_time();
    for i in 0..repeats {
        model.run(vec![input(i)])?;
    }
    Ok((humem_perception::cpu::process_cpu_time() - started).as_secs_f64() * 1e3 / repeats as f64)
}

/// Part 0: core milliseconds per keyframe of each model at each precision
/// (one intra-op thread, batch 1). A keyframe costs one descriptor (+
/// scene) inference, one text detection and one recognition per text
/// line; the sum counts one line. Precisions whose file is missing are
/// left out.
fn core_time(
    p: &PerceptionConfig,
    decoded: &[image::RgbImage],
    repeats: usize,
) -> anyhow::Result<()> {
    let env = runtime::environment(&p.onnxruntime_library())?;
    let options = SessionOptions {
        intra_threads: 1,
        ..p.session_options()
    };
    let precisions = [Precision::Fp32, Precision::Int8];
    // [model][precision]: core ms, None where the file is missing.
    let mut table: Vec<(&str, [Option<f64>; 2])> = Vec::new();
    let d = &p.descriptor;
    let global_inputs = descriptor_inputs(p, decoded);
    let mut row = [None; 2];
    for (slot, &precision) in row.iter_mut().zip(&precisions) {
        let Ok(path) = p.model_file(&d.model, precision) else {
            continue;
        };
        let mut outputs = vec![d.output.clone()];
        if let Some(s) = p.scene.as_ref().filter(|s| s.model == d.model) {
            outputs.push(s.output.clone());
        }
        let mut model = ImageModel::new(
            "descriptor",
            runtime::session(&env, &path, precision.options(options))?,
            &d.input,
            &outputs,
            Some([d.width as usize, d.height as usize]),
        )?;
        *slot = Some(core_ms(
            &mut model,
            &|i| global_inputs[i % global_inputs.len()].clone(),
            repeats,
        )?);
    }
    table.push(("descriptor+scene", row));
    if let Some(o) = &p.ocr {
        let dictionary = Arc::new(ocr::ctc::Dictionary::load(&p.resolve(&o.dictionary))?);
        let det_inputs = detector_inputs(o, decoded);
        let lines = line_inputs(o, decoded);
        let (mut det_row, mut rec_row) = ([None; 2], [None; 2]);
        for (k, &precision) in precisions.iter().enumerate() {
            let (Ok(det), Ok(rec)) = (
                p.model_file(&o.detector, precision),
                p.model_file(&o.recognizer, precision),
            ) else {
                continue;
            };
            let sessions = vec![(
                runtime::session(&env, &det, precision.options(options))?,
                runtime::session(&env, &rec, precision.options(options))?,
            )];
            let mut models = OcrModels::new(sessions, o, dictionary.clone())?;
            det_row[k] = Some(core_ms(
                &mut models.detectors[0],
                &|i| det_inputs[i % det_inputs.len()].clone(),
                repeats,
            )?);
            rec_row[k] = Some(core_ms(
                &mut models.recognizers[0],
                &|i| copy_line(&lines[i % lines.len()]),
                repeats,
            )?);
        }
        table.push(("ocr detection", det_row));
        table.push(("ocr recognition", rec_row));
    }
    let sum = |k: usize| table.iter().map(|(_, r)| r[k]).sum::<Option<f64>>();
    let total = [sum(0), sum(1)];
    println!("\n0. core milliseconds per keyframe, one intra-op thread, batch 1 (CPU time of the process)");
    println!("| model | fp32 | int8 | int8 / fp32 |");
    println!("| --- | --- | --- | --- |");
    let cell = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
    for (name, r) in table
        .iter()
        .chain([("per keyframe (one text line)", total)].iter())
    {
        let ratio = r[0]
            .zip(r[1])
            .map_or("-".to_string(), |(a, b)| format!("{:.2}x", b / a));
        println!("| {name} | {} | {} | {ratio} |", cell(r[0]), cell(r[1]));
    }
    Ok(())
}

/// Part 0b: what a keyframe of a stream costs a core through the whole
/// pipeline (decoding, descriptor+scene, OCR on the lines it finds, the
/// thumbnail), one intra-op thread, batch 1, the images sent in order as
/// one session: every model in fp32 (the baseline), the configured
/// precisions, and the configured precisions with objects carried over
/// between similar keyframes (`perception.reuse`; where the configuration
/// has it off, `max_carried` 2 at the configured `min_similarity`).
async fn stream_core_time(config: &Config, images: &[Vec<u8>]) -> anyhow::Result<()> {
    let one_thread = |mut p: PerceptionConfig| {
        p.intra_threads = 1;
        p.workers = 1;
        p.max_batch = 1;
        p
    };
    let configured = one_thread(PerceptionConfig {
        reuse: ReuseConfig {
            max_carried: 0,
            ..config.perception.reuse.clone()
        },
        ..config.perception.clone()
    });
    let mut fp32 = configured.clone();
    fp32.descriptor.precision = Some(Precision::Fp32);
    if let Some(scene) = &mut fp32.scene {
        scene.precision = Some(Precision::Fp32);
    }
    if let Some(ocr) = &mut fp32.ocr {
        ocr.detector_precision = Precision::Fp32;
        ocr.recognizer_precision = Precision::Fp32;
    }
    if let Some(detector) = &mut fp32.detector {
        detector.precision = Precision::Fp32;
    }
    let reuse = if config.perception.reuse.enabled() {
        config.perception.reuse.clone()
    } else {
        ReuseConfig {
            max_carried: 2,
            ..config.perception.reuse.clone()
        }
    };
    let carrying = PerceptionConfig {
        reuse: reuse.clone(),
        ..configured.clone()
    };
    println!(
        "\n0b. core milliseconds per keyframe, whole pipeline, one intra-op thread, batch 1, the {} images in order as one session",
        images.len()
    );
    println!("| pipeline | core ms | carried | vs fp32 |");
    println!("| --- | --- | --- | --- |");
    let mut baseline = None;
    for (name, p) in [
        ("every model fp32, every keyframe read".to_string(), fp32),
        ("configured precisions".to_string(), configured),
        (
            format!(
                "configured + reuse (max_carried {}, min_similarity {})",
                reuse.max_carried, reuse.min_similarity
            ),
            carrying,
        ),
    ] {
        let top_k = config.store.scene_top_k;
        let perception = tokio::task::spawn_blocking(move || Perception::load(&p, top_k))
            .await
            .context("loading the models")??;
        for data in images.iter().take(2) {
            perception.extract(ImageInput::file(data.clone())).await?;
        }
        let mut carried = 0;
        let started = humem_perception::cpu::process_cpu_time();
        for data in images {
            let extracted = perception
                .extract_in(ImageInput::file(data.clone()), Some("bench"))
                .await?;
            carried += usize::from(extracted.objects_carried);
        }
        let ms = (humem_perception::cpu::process_cpu_time() - started).as_secs_f64() * 1e3
            / images.len().max(1) as f64;
        let base = *baseline.get_or_insert(ms);
        println!(
            "| {name} | {ms:.1} | {carried}/{} | {:.2}x |",
            images.len(),
            ms / base
        );
    }
    Ok(())
}

/// The descriptor model's inputs for `decoded`.
fn descriptor_inputs(p: &PerceptionConfig, decoded: &[image::RgbImage]) -> Vec<Planes> {
    let d = &p.descriptor;
    decoded
        .iter()
        .map(|i| {
            let resized = img::resize(i, d.width, d.height);
            let mut data = Vec::new();
            img::append_chw(&resized, img::Channels::Rgb, d.mean, d.std, &mut data);
            Planes {
                width: d.width as usize,
                height: d.height as usize,
                data,
            }
        })
        .collect()
}

/// The text detector's inputs: each whole image at the configured long
/// side.
fn detector_inputs(o: &OcrConfig, decoded: &[image::RgbImage]) -> Vec<Planes> {
    decoded
        .iter()
        .map(|i| canvas::detector_input(i, whole(i), o.detector_long_side).0)
        .collect()
}

/// Text lines for the recogniser: a strip of each image, 6:1 like a short
/// sign.
fn line_inputs(o: &OcrConfig, decoded: &[image::RgbImage]) -> Vec<ocr::LineInput> {
    decoded
        .iter()
        .map(|i| {
            let (w, h) = (i.width() as f32, i.height() as f32);
            let quad = [
                [0.2 * w, 0.45 * h],
                [0.8 * w, 0.45 * h],
                [0.8 * w, 0.55 * h],
                [0.2 * w, 0.55 * h],
            ];
            ocr::line_input(i, quad, o.line_height, o.max_line_width)
        })
        .collect()
}

fn copy_line(l: &ocr::LineInput) -> ocr::LineInput {
    ocr::LineInput {
        width: l.width,
        data: l.data.clone(),
    }
}

/// Part 1: each model alone, called directly, per batch size; then text
/// detection at the camera's shape against the old letterbox.
fn models_alone(
    p: &PerceptionConfig,
    decoded: &[image::RgbImage],
    repeats: usize,
) -> anyhow::Result<()> {
    let env = runtime::environment(&p.onnxruntime_library())?;
    let options = p.session_options();
    println!("\n1. models called directly, per batch (ms)");
    println!(
        "{:<18} {:>5} {:>10} {:>10} {:>12} {:>10}",
        "model", "batch", "mean", "p95", "per input", "vs batch 1"
    );
    let d = &p.descriptor;
    let mut outputs = vec![d.output.clone()];
    if let Some(s) = p.scene.as_ref().filter(|s| s.shares_input_with(d)) {
        outputs.push(s.output.clone());
    }
    let mut global = ImageModel::new(
        "descriptor",
        runtime::session(
            &env,
            &p.model_file(&d.model, d.precision())?,
            d.precision().options(options),
        )?,
        &d.input,
        &outputs,
        Some([d.width as usize, d.height as usize]),
    )?;
    let global_inputs = descriptor_inputs(p, decoded);
    time_model(
        "descriptor+scene",
        &mut global,
        &|i| global_inputs[i % global_inputs.len()].clone(),
        repeats,
    )?;
    if let Some(o) = &p.ocr {
        let dictionary = ocr::ctc::Dictionary::load(&p.resolve(&o.dictionary))?;
        let sessions = vec![(
            runtime::session(
                &env,
                &p.model_file(&o.detector, o.detector_precision)?,
                o.detector_precision.options(options),
            )?,
            runtime::session(
                &env,
                &p.model_file(&o.recognizer, o.recognizer_precision)?,
                o.recognizer_precision.options(options),
            )?,
        )];
        let mut models = OcrModels::new(sessions, o, Arc::new(dictionary))?;
        let det_inputs = detector_inputs(o, decoded);
        time_model(
            "ocr detection",
            &mut models.detectors[0],
            &|i| det_inputs[i % det_inputs.len()].clone(),
            repeats,
        )?;
        let lines = line_inputs(o, decoded);
        time_model(
            "ocr recognition",
            &mut models.recognizers[0],
            &|i| copy_line(&lines[i % lines.len()]),
            repeats,
        )?;
        compare_detection_shapes(&mut models.detectors[0], decoded, &det_inputs, o, repeats)?;
    }

    Ok(())
}

/// Part 2: the whole pipeline under concurrent clients, unbatched then
/// batched; returns the batched run's stage timings.
async fn pipeline_under_load(
    config: &Config,
    images: &Arc<Vec<Vec<u8>>>,
    args: &PerceptionBench,
) -> anyhow::Result<Vec<Vec<(&'static str, Duration)>>> {
    let p = &config.perception;
    let top_k = config.store.scene_top_k;
    let mut unbatched_config = p.clone();
    unbatched_config.max_batch = 1;
    let mut batched_config = p.clone();
    batched_config.max_batch = args.batch.max(2);
    let unbatched = Perception::load(&unbatched_config, top_k)?;
    let batched = Perception::load(&batched_config, top_k)?;
    drive(&batched, images, 1, 2).await?;
    drive(&unbatched, images, 1, 2).await?;
    println!(
        "\n2. whole pipeline (decode, descriptor+scene, OCR), {} clients x {} images; gain = throughput vs unbatched",
        args.clients, args.requests
    );
    println!(
        "{:<30} {:>10} {:>10} {:>10} {:>8}",
        "", "images/s", "mean ms", "p95 ms", "gain"
    );
    // One client alone: the latency a single SLAM client sees.
    let (wall, latencies, _) = drive(&batched, images, 1, args.requests).await?;
    let (mean, p95) = summary(&latencies);
    println!(
        "{:<30} {:>10.1} {mean:>10.1} {p95:>10.1} {:>8}",
        "1 client (batched run's config)",
        latencies.len() as f64 / wall.as_secs_f64(),
        ""
    );
    let mut baseline = 0.0;
    let mut batched_timings = Vec::new();
    for (name, perception, max_batch) in [
        ("unbatched (max_batch 1)", &unbatched, 1),
        ("batched", &batched, batched_config.max_batch),
    ] {
        let (wall, latencies, timings) =
            drive(perception, images, args.clients, args.requests).await?;
        let rate = latencies.len() as f64 / wall.as_secs_f64();
        if max_batch == 1 {
            baseline = rate;
        } else {
            batched_timings = timings;
        }
        let (mean, p95) = summary(&latencies);
        let label = if max_batch == 1 {
            name.to_string()
        } else {
            format!("{name} (max_batch {max_batch}, {} ms)", p.max_wait_ms)
        };
        println!(
            "{label:<30} {rate:>10.1} {mean:>10.1} {p95:>10.1} {:>7.2}x",
            rate / baseline
        );
    }

    Ok(batched_timings)
}

/// Part 3: the stages of the batched run (queueing included).
fn stage_table(timings: &[Vec<(&'static str, Duration)>]) {
    println!("\n3. stages of the batched run (ms, queueing included)");
    println!("{:<12} {:>10} {:>10}", "stage", "mean", "p95");
    let mut stages: Vec<&'static str> = Vec::new();
    for t in timings.iter().flatten() {
        if !stages.contains(&t.0) {
            stages.push(t.0);
        }
    }
    for stage in stages {
        let samples: Vec<Duration> = timings
            .iter()
            .flatten()
            .filter(|t| t.0 == stage)
            .map(|t| t.1)
            .collect();
        let (mean, p95) = summary(&samples);
        println!("{stage:<12} {mean:>10.1} {p95:>10.1}");
    }
}
