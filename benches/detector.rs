//! Image to heat maps, one core: each step of the image detector on its own.
//! - the crop: a 640 x 480 frame resampled into the 256 x 256 input;
//! - each BlazePose landmark model on one crop (tract);
//! - the channel mapping: 39 logit channels to the dictionary's 17 joint maps;
//! - the person detector on one 224 x 224 input, decoding and NMS included (runs on the
//!   first frame and after a loss only).
//!
//! A tracked frame costs crop + landmark model + mapping. Fetches the models into the
//! cache first (`posestream models fetch`). With `$POSESTREAM_LITERT` naming LiteRT's
//! `libLiteRt.so`, the models also run on LiteRT, side by side; the landmark models
//! also run with tract's matrix products spread over the cores.

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::CropBox;
use posestream::LoadDictionary;
use posestream::detector::crop::crop_input;
use posestream::detector::mapping::ChannelMapping;
use posestream::models::landmarks::{HEATMAP_CHANNELS, HEATMAP_SIZE, INPUT_SIZE, LandmarkNetwork};
use posestream::models::litert::{LiteRt, LiteRtNetwork};
use posestream::models::person::{self, PersonNetwork};
use posestream::models::{self, LandmarkModel, ModelFile};

fn bench(c: &mut Criterion) {
    let dir = models::cache_dir();
    let fetched = models::fetch(&dir, &LandmarkModel::ALL, None, false).expect("models");
    // A synthetic image (the cost does not depend on the content).
    let rgb: Vec<f32> = (0..INPUT_SIZE * INPUT_SIZE * 3)
        .map(|i| ((i * 7919) % 255) as f32 / 255.0)
        .collect();
    // LiteRT beside tract when its library is named (`$POSESTREAM_LITERT`).
    let litert = LiteRt::library_path(std::path::Path::new(""))
        .map(|p| LiteRt::load(&p).expect("$POSESTREAM_LITERT loads"));
    let mut group = c.benchmark_group("image to heat maps (one core)");
    group.sample_size(20);
    let frame = image::RgbImage::from_fn(640, 480, |x, y| {
        image::Rgb([(x % 251) as u8, (y % 241) as u8, ((x + y) % 239) as u8])
    });
    let crop = CropBox::new(180.0, 40.0, 300.0, 300.0).expect("box");
    let mut input = Vec::new();
    group.bench_function("crop 640x480 -> 256x256", |b| {
        b.iter(|| crop_input(&frame, &crop, INPUT_SIZE, &mut input))
    });
    for m in &fetched {
        let ModelFile::Landmark(model) = m.model else {
            continue;
        };
        let network = LandmarkNetwork::load(&m.for_tract).expect("loads");
        group.bench_function(format!("landmarks {model:?}"), |b| {
            b.iter(|| network.run(&rgb).expect("runs"))
        });
        group.bench_function(format!("landmarks {model:?}, spread over the cores"), |b| {
            b.iter(|| network.run_spread(&rgb).expect("runs"))
        });
        if let Some(runtime) = &litert {
            let mut compiled = LiteRtNetwork::load(runtime, &m.original, 1).expect("compiles");
            group.bench_function(format!("landmarks {model:?}, LiteRT"), |b| {
                b.iter(|| compiled.run(&rgb).expect("runs"))
            });
        }
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let dict = posestream::Dictionary::load(root.join("config/dictionaries/default-k128.json"))
        .expect("dictionary");
    let mapping = ChannelMapping::load(
        root.join("config/detectors/blazepose.toml"),
        &dict.skeleton().joints,
    )
    .expect("mapping");
    let logits: Vec<f32> = (0..HEATMAP_SIZE * HEATMAP_SIZE * HEATMAP_CHANNELS)
        .map(|i| ((i % 97) as f32 - 60.0) * 0.1)
        .collect();
    let mut maps = Vec::new();
    group.bench_function("mapping 39 channels -> 17 joints", |b| {
        b.iter(|| {
            mapping
                .apply(&logits, HEATMAP_SIZE, HEATMAP_SIZE, &mut maps)
                .expect("maps")
        })
    });
    let detector = PersonNetwork::load(&ModelFile::PersonDetector.for_tract(&dir)).expect("loads");
    let input: Vec<f32> = (0..person::INPUT_SIZE * person::INPUT_SIZE * 3)
        .map(|i| ((i * 7919) % 255) as f32 / 127.5 - 1.0)
        .collect();
    group.bench_function("person detector 224x224", |b| {
        b.iter(|| detector.detect(Some(0), &input, 0.5).expect("runs"))
    });
    if let Some(runtime) = &litert {
        let fast =
            PersonNetwork::load_litert(runtime, &ModelFile::PersonDetector.original(&dir), 1)
                .expect("compiles");
        group.bench_function("person detector 224x224, LiteRT", |b| {
            b.iter(|| fast.detect(Some(0), &input, 0.5).expect("runs"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
