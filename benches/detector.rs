//! Image crop to heat maps: one 256 x 256 crop through each BlazePose landmark model in
//! tract, one core. Fetches the models into the cache first (`posestream models fetch`).

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::models::landmarks::{INPUT_SIZE, LandmarkNetwork};
use posestream::models::{self, LandmarkModel};

fn bench(c: &mut Criterion) {
    let dir = models::cache_dir();
    let fetched = models::fetch(&dir, &LandmarkModel::ALL, None, false).expect("models");
    // A smooth synthetic image (the cost does not depend on the content).
    let rgb: Vec<f32> = (0..INPUT_SIZE * INPUT_SIZE * 3)
        .map(|i| ((i * 7919) % 255) as f32 / 255.0)
        .collect();
    let mut group = c.benchmark_group("crop to heat maps (256 x 256, one core)");
    group.sample_size(20);
    for m in &fetched {
        let network = LandmarkNetwork::load(&m.for_tract).expect("loads");
        group.bench_function(format!("{:?}", m.model), |b| {
            b.iter(|| network.run(&rgb).expect("runs"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
